"""A map loaded for localisation: a :class:`~seqnet.methods.protocol.Reference` on disk.

The descriptor arrays stay memory-mapped (copy-on-write: torch reads them without a copy, and
nothing is ever written back to the files); exact search and whole-map matching stream over
reference blocks, re-ranking reads only the candidates' windows. A map serves one HVPR method (its
shortlist descriptor and its ``<frames>+<matcher>`` re-ranker), its shortlister alone and its
matcher over the whole map.
"""

from __future__ import annotations

import copy
import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.devices import get_device
from ..core.errors import ConfigError, DatasetError
from ..core.lazy import lazy_module
from ..core.memory import BLOCK_BYTES as MEMORY_BLOCK
from ..core.provenance import check_same
from ..core.tensors import ArrayLike
from ..data.traverse import Traverse
from ..matching.hvpr import hvpr_search
from ..matching.on_disk import pair_scores_on_map
from ..matching.registry import SEQUENCE_MATCHERS
from ..methods.grammar import HVPR_FUSED, HVPR_RERANK, Method, parse_method
from ..search.ann import search as ann_search
from ..search.knn import ExactIndex
from ..security.digests import verify_digests
from ..security.jsonfile import read_json
from ..sequence.described import Described
from ..sequence.windows import Windows, window_offset
from .config import MapConfig
from .edges import edge_frames, edge_rows, search_every_frame
from .store import MAP_FORMAT, MAP_JSON, PCA_FILE

torch = lazy_module("torch")

if TYPE_CHECKING:
    from ..sequence.model import SeqNet

BLOCK_BYTES = MEMORY_BLOCK  # working memory of one block of a whole-map search (the map itself stays mapped)


class MapError(DatasetError):
    """A map directory is missing, malformed, or does not fit the queries."""


class Map:
    """A map directory opened by :func:`seqnet.maps.load_map` (attributes are read-only by convention).

    Attributes:
        path: the directory; config: its :class:`MapConfig`; meta: ``map.json``; windows: its windows.
        shortlist: ``[R, D1]`` memory map; frames: ``[Nr, D2]`` memory map (float32 or float16).
        items, match_starts: ``[R]``; positions: ``[Nr, P]``; names: ``Nr`` names or None.
        edge_shortlist: ``[E, D1]`` shortlist descriptors of the frames that are no item, when the map stores them
            (:mod:`seqnet.maps.edges`), else None.
        index: the FAISS index (None for ``flat``: exact search over ``shortlist``).
        models: the models stored with the map, by role; device: torch device of the computations.
    """

    def __init__(self, path: Path, meta: dict[str, Any], arrays: dict[str, Any], index: Any,
                 models: dict[str, SeqNet], device: str | None = None, anchor: str = "") -> None:
        self.path, self.meta, self.config = path, meta, MapConfig.from_dict(meta["config"])
        self.windows = Windows(self.config.windows.seq_len, self.config.windows.match_len, self.config.window, anchor)
        self.shortlist, self.frames = arrays["shortlist"], arrays["frames"]
        self.items, self.match_starts = np.asarray(arrays["items"]), np.asarray(arrays["match_starts"])
        self.positions, self.seq_bounds = np.asarray(arrays["positions"]), arrays.get("seq_bounds")
        self.names: list[str] | None = arrays.get("names")
        self.edge_shortlist = arrays.get("edge_shortlist")
        self._every_frame: tuple[np.ndarray, np.ndarray, ArrayLike] | None = None  # a single-frame view's search
        self.index, self.models, self.device = index, models, get_device(device)
        self.block_bytes = BLOCK_BYTES
        self.name = str(path.name)
        self._exact: dict[int, ExactIndex] = {}
        self.precision: torch.dtype | None = None  # half: exact searches read and multiply in it (the localiser)
        self.resident = False  # exact searches keep what they search in memory (the localiser)
        self.frame_indices = False  # query frames are descriptors
        for model in models.values():
            model.to(self.device).eval()

    @property
    def provenance(self) -> dict | None:
        """How the raw reference descriptors were made (queries must match)."""
        return self.meta.get("provenance")

    @property
    def input_dim(self) -> int:
        """D of the raw descriptors the map's models read (the frame D for maps made from arrays)."""
        return int(self.meta.get("input_dim") or self.frames.shape[1])

    @property
    def pca_file(self) -> Path | None:
        """The map's copy of the ``--pca D`` PCA that reduced its descriptors (``pca.npz``), its every byte checked
        against the map's checksum (opening the map checks a sample); None for a map without one (reduced by no PCA,
        or built before seqnet copied it)."""
        rel = self.meta.get("pca")
        if rel is None:
            return None
        checksums = self.meta.get("checksums") if isinstance(self.meta.get("checksums"), dict) else {}
        if rel != PCA_FILE or PCA_FILE not in checksums:
            raise MapError(f"{self.path / MAP_JSON}: 'pca' must be {PCA_FILE!r}, a file of its checksums, got "
                           f"{str(rel)[:80]!r} (the map is damaged; rebuild it)")
        verify_digests(self.path, {PCA_FILE: checksums[PCA_FILE]}, MapError, "map",
                       "a map is written whole: rebuild it with seqnet index build", full=True)
        return self.path / PCA_FILE

    @property
    def nbytes(self) -> int:
        """Bytes of the map's files."""
        return sum(p.stat().st_size for p in self.path.rglob("*") if p.is_file())

    def check_query(self, dim: int, provenance: dict | None, allow: bool = False) -> None:
        """Refuse query descriptors of another D or provenance than the map's (unless ``allow``)."""
        if dim != self.input_dim:
            raise MapError(f"the query descriptors have D={dim} but the map {self.path} was built from D="
                           f"{self.input_dim} descriptors; hint: describe the queries as the map's reference was")
        check_same(self.provenance, provenance, f"the reference descriptors of map {self.path}",
                   "the query descriptors", allow)

    def served(self) -> dict[str, Method]:
        """The methods the map serves, by name: its HVPR, its shortlister (k-NN), its whole-map matcher and,
        on an S_L map, ``hvpr-fused`` (the fused score needs only the stored S_L distances)."""
        m = self.config.method
        served = [m, parse_method(m.shortlist), parse_method(m.rerank)]
        if m.shortlist == "seqnet":
            served.append(parse_method(HVPR_FUSED if m.rerank == HVPR_RERANK else f"{HVPR_FUSED}:{m.rerank}"))
        return {x.name: x for x in served}

    def serve_online(self, precision: torch.dtype | None = None) -> None:
        """Searched frame by frame (the localiser): exact searches keep what they read resident, in ``precision``."""
        self.resident = True
        if precision is not None:
            self.precision = precision

    def check_method(self, m: Method) -> None:
        """Refuse a method the map does not serve (a method is what it runs, not how it is named)."""
        served = self.served()
        if dataclasses.replace(m, name="") not in {dataclasses.replace(x, name="") for x in served.values()}:
            raise ConfigError(f"map {self.path} cannot run method {m.name!r}; valid for this map: {', '.join(served)}")

    def prepare(self, m: Method) -> float:
        """Nothing to describe: the map stores its descriptors."""
        return 0.0

    def search(self, descriptor: str, query: ArrayLike, k: int, exact: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """``(distances [M, k], items [M, k])`` of the nearest items by the shortlist descriptor: through
        the index, or exactly (``exact`` or a ``flat`` map) by streaming over ``shortlist``."""
        if descriptor != self.config.shortlist:
            raise ConfigError(f"map {self.path} stores {self.config.shortlist!r} shortlist descriptors, not "
                              f"{descriptor!r}")
        if self._every_frame is not None:  # a single-frame method's view: items merged with the other frames
            items, edges, rows = self._every_frame
            return search_every_frame(items, edges, lambda n: self._search_items(query, n, exact),
                                      lambda n: self.exact_search(rows).search(query, n), k)
        return self._search_items(query, k, exact)

    def _search_items(self, query: ArrayLike, k: int, exact: bool) -> tuple[np.ndarray, np.ndarray]:
        if exact or self.index is None:
            return self.exact_search(self.shortlist).search(query, k)
        q = query.cpu().numpy() if isinstance(query, torch.Tensor) else query
        return ann_search(self.index, q, k)

    def for_method(self, m: Method) -> Map:
        """The map as ``m`` searches it: itself, or for a single-frame method (``single``, ``s1``: no window) a view
        whose items are every reference frame and whose windows are one frame, as a dataset's reference is for that
        method (:mod:`seqnet.maps.edges`); :class:`MapError` when the map lacks the descriptors of its frames that
        are no item (a map built before seqnet stored them)."""
        self.check_method(m)
        if not m.single_frame:
            return self
        same = self.config.frames_descriptor == self.config.shortlist  # the stored frames are the shortlist's
        view = copy.copy(self)
        view.windows = Windows(1, 1, self.windows.mode, self.windows.anchor)
        view.items = view.match_starts = np.arange(len(self.frames), dtype=np.int64)
        view._exact = {}
        if self.index is None and same:
            view.shortlist = self.frames  # exact search over the stored frames: every frame, one search
            return view
        edges = edge_frames(self.items, len(self.frames))
        rows = self.edge_shortlist
        if rows is None and len(edges) and same:
            rows = edge_rows(self.frames, edges)
        if rows is None and len(edges):
            raise MapError(f"map {self.path} stores the {self.config.shortlist!r} descriptors of its {len(self.items)} "
                           f"items only, not of the {len(edges)} frames where no window fits, which {m.name!r} "
                           "searches too (a map built before seqnet stored them); rebuild it with seqnet index build")
        view._every_frame = (self.items, edges, rows if rows is not None else self.shortlist[:0])
        return view

    def exact_search(self, ref: ArrayLike) -> ExactIndex:
        """The exact index of one of the map's arrays (``shortlist`` or ``frames``; its norms are kept)."""
        if id(ref) not in self._exact or self._exact[id(ref)].ref is not ref:
            self._exact[id(ref)] = ExactIndex(ref, self.device, self.block_bytes, keep=isinstance(ref, torch.Tensor),
                                              precision=self.precision, resident=self.resident)
        return self._exact[id(ref)]

    def match(self, frames: str, matcher: str, query_frames: ArrayLike, q_starts: np.ndarray,
              k: int) -> tuple[np.ndarray, np.ndarray]:
        """The map's matcher over the whole map (streamed over reference blocks): ``(scores [M, k], items [M, k])``
        of the query windows ``q_starts [M]`` of ``query_frames [Nq, D2]``."""
        self._check_frames(frames, matcher)
        spec = SEQUENCE_MATCHERS[matcher]
        return spec.topk(query_frames, self.frames, self.config.windows.match_len, k, q_starts, self.match_starts,
                         device=str(self.device), block_bytes=self.block_bytes, **spec.options(self.windows.anchor))

    def frame_distances(self, frames: str, frame: torch.Tensor) -> torch.Tensor:
        """``[Nr]`` distances of one query frame descriptor ``[D2]`` to every stored frame (streamed in blocks)."""
        if frames != self.config.frames_descriptor:
            raise ConfigError(f"map {self.path} stores {self.config.frames_descriptor!r} frames, not {frames!r}")
        return self.exact_search(self.frames).distances(frame[None])[0]

    def shared_distances(self, frames: str, query_frames: ArrayLike) -> None:
        """None: a map's shortlist comes from its index (nothing to share with the re-ranking)."""
        return None

    def rerank(self, frames: str, matcher: str, query_frames: ArrayLike, q_starts: np.ndarray,
               candidates: np.ndarray) -> torch.Tensor:
        """The matcher's scores ``[M, K]`` of ``candidates [M, K]`` (items, -1 = none), in candidate order."""
        self._check_frames(frames, matcher)
        return self.pair_scores(query_frames, q_starts, candidates)

    def pair_scores(self, query_frames: ArrayLike, q_starts: np.ndarray, candidates: np.ndarray,
                    seq_len: int | None = None) -> torch.Tensor:
        """The map's matcher on ``candidates [M, K]`` for query windows of ``seq_len`` (default L_m) frames."""
        seq_len = seq_len or self.config.windows.match_len
        return pair_scores_on_map(query_frames, self.frames, seq_len, q_starts, self.match_starts_for(seq_len),
                                  candidates, self.config.method.matcher, str(self.device), anchor=self.windows.anchor)

    def _check_frames(self, frames: str, matcher: str) -> None:
        if (frames, matcher) != (self.config.frames_descriptor, self.config.method.matcher):
            raise ConfigError(f"map {self.path} stores {self.config.rerank!r} for re-ranking, not "
                              f"{frames!r} frames with {matcher!r}")

    def match_starts_for(self, seq_len: int) -> np.ndarray:
        """``[R]`` window starts of the items for another L_m (clipped into the traverse)."""
        if seq_len == self.config.windows.match_len:
            return self.match_starts
        starts = self.items - window_offset(seq_len, self.config.window)
        return np.clip(starts, 0, len(self.frames) - seq_len)

    def localize(self, shortlist_query: ArrayLike, query_frames: ArrayLike, q_starts: np.ndarray, top_k: int = 20,
                 k: int | None = None, exact: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """The map's HVPR (:func:`seqnet.matching.hvpr.hvpr_search`, the one assembly) for query items
        ``shortlist_query [M, D1]`` with windows ``q_starts`` of ``query_frames``."""
        return hvpr_search(lambda n: self.search(self.config.shortlist, shortlist_query, n, exact),
                           lambda c: self.pair_scores(query_frames, q_starts, c), self.windows.match_len, top_k, k)

    def describe(self, traverse: Traverse) -> Described:
        """The query items of ``traverse`` (windows as the map's), described by the map's models on demand."""
        return Described(traverse.descriptors, traverse.seq_bounds, self.windows, self.models, self.device, "query")

    def describe_info(self) -> str:
        """One line: size, descriptors, index."""
        c = self.config
        return (f"map {self.path}: {len(self.items)} items / {len(self.frames)} frames, {c.method.name} "
                f"(L={c.windows.seq_len}, L_m={c.windows.match_len}, {c.window}), index {c.ann.kind}, {c.dtype}")


def read_meta(path: Path) -> dict[str, Any]:
    """``map.json`` of a map directory (:class:`MapError` when it is not one)."""
    if not path.is_dir():
        raise MapError(f"map directory not found: {path}" + (" (it is a file)" if path.exists() else ""))
    if not (path / MAP_JSON).exists():
        raise MapError(f"{path} is not a seqnet map: {MAP_JSON} is missing (hint: seqnet index build)")
    meta = read_json(path / MAP_JSON, MAP_JSON, MapError)
    if not isinstance(meta, dict) or meta.get("format") != MAP_FORMAT:
        got = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
        raise MapError(f"{path / MAP_JSON}: format {got!r} is not {MAP_FORMAT!r}")
    return meta
