"""Maps: the reference side prepared once for localisation (``seqnet index build``, ``seqnet eval --index``).

A map directory holds the shortlist descriptors of every reference item with an ANN index over
them, the frame descriptors used for re-ranking (memory-mapped at use, float32 or float16), the
items' frames and window starts, positions and names, the models, the resolved
:class:`MapConfig` and the provenance of the descriptors (queries of another provenance or D are
refused). Modules: :mod:`.config`, :mod:`.store` (writing), :mod:`.build` (from a dataset), :mod:`.shards`
(an IVF index built in shards), :mod:`.map` / :mod:`.load` (the :class:`Map` API, re-ranking included),
:mod:`.evaluate` (``seqnet eval --index``).
"""

from .build import build
from .config import MapConfig
from .evaluate import evaluate_map, load_query
from .evaluate import main as evaluate_main
from .load import load_map
from .map import Map, MapError
from .store import MapArrays, is_map_file, write_map

__all__ = ["Map", "MapArrays", "MapConfig", "MapError", "build", "evaluate_main", "evaluate_map",
           "is_map_file", "load_map", "load_query", "write_map"]
