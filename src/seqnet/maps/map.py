"""A map loaded for localisation: shortlist search, re-ranking, HVPR, and the query descriptors it expects.

The descriptor arrays stay memory-mapped (copy-on-write: torch reads them without a copy, and
nothing is ever written back to the files); exact search and whole-map matching stream over
reference blocks, re-ranking reads only the candidates' windows.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..core.errors import DatasetError
from ..core.provenance import check_same
from ..core.utils import ArrayLike, get_device
from ..data.traverse import Traverse
from ..eval.features import Side
from ..matching.registry import SEQUENCE_MATCHERS
from ..search.ann import search as ann_search
from ..sequence.descriptors import SEQUENCE_DESCRIPTORS, SeqNet, describe_windows
from ..sequence.windows import window_frames, window_indices, window_offset
from .config import MapConfig
from .rerank import rerank_on_map
from .search import ExactSearch
from .store import MAP_FORMAT, MAP_JSON

BLOCK_BYTES = 64 * 2**20  # working memory of one block of a whole-map search (the map itself stays mapped)


class MapError(DatasetError):
    """A map directory is missing, malformed, or does not fit the queries."""


@dataclasses.dataclass
class QueryDescriptors:
    """What a query traverse needs for a map: its items and descriptors (ms spent on each)."""

    side: Side
    shortlist: torch.Tensor  # [M, D1] shortlist descriptors of the query items
    frames: torch.Tensor  # [Nq, D2] re-ranking descriptors of every query frame
    ms: dict[str, float]


class Map:
    """A map directory opened by :func:`seqnet.maps.load_map` (attributes are read-only by convention).

    Attributes:
        path: the directory; config: its :class:`MapConfig`; meta: ``map.json``.
        shortlist: ``[R, D1]`` memory map; frames: ``[Nr, D2]`` memory map (float32 or float16).
        items, match_starts: ``[R]``; positions: ``[Nr, P]``; names: ``Nr`` names or None.
        index: the FAISS index (None for ``flat``: exact search over ``shortlist``).
        models: the models stored with the map, by role; device: torch device of the computations.
    """

    def __init__(self, path: Path, meta: dict[str, Any], arrays: dict[str, Any], index: Any,
                 models: dict[str, SeqNet], device: str | None = None) -> None:
        self.path, self.meta, self.config = path, meta, MapConfig.from_dict(meta["config"])
        self.shortlist, self.frames = arrays["shortlist"], arrays["frames"]
        self.items, self.match_starts = np.asarray(arrays["items"]), np.asarray(arrays["match_starts"])
        self.positions, self.seq_bounds = np.asarray(arrays["positions"]), arrays.get("seq_bounds")
        self.names: list[str] | None = arrays.get("names")
        self.index, self.models, self.device = index, models, get_device(device)
        self.block_bytes = BLOCK_BYTES
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

    def search(self, shortlist_query: ArrayLike, k: int, exact: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """``(distances [M, k], items [M, k])`` of the nearest items by the shortlist descriptor: through
        the index, or exactly (``exact`` or a ``flat`` map) by streaming over ``shortlist``."""
        if exact or self.index is None:
            return self.exact_search(self.shortlist)(shortlist_query, k)
        q = shortlist_query.cpu().numpy() if isinstance(shortlist_query, torch.Tensor) else shortlist_query
        return ann_search(self.index, q, k)

    def exact_search(self, ref: ArrayLike) -> ExactSearch:
        """The exact searcher of one of the map's arrays (``shortlist`` or ``frames``; its norms are kept)."""
        cache = self.__dict__.setdefault("_searchers", {})
        if id(ref) not in cache or cache[id(ref)].ref is not ref:
            cache[id(ref)] = ExactSearch(ref, self.device, self.block_bytes)
        return cache[id(ref)]

    def match(self, query_frames: ArrayLike, q_starts: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The map's matcher over the whole map (streamed over reference blocks): ``(scores [M, k], items [M, k])``
        of the query windows ``q_starts [M]`` of ``query_frames [Nq, D2]``."""
        spec = SEQUENCE_MATCHERS[self.config.method.matcher]
        return spec.topk(query_frames, self.frames, self.config.match_len, k, q_starts, self.match_starts,
                         device=str(self.device), block_bytes=self.block_bytes, **spec.options(self.config.window))

    def match_starts_for(self, seq_len: int) -> np.ndarray:
        """``[R]`` window starts of the items for another L_m (clipped into the traverse)."""
        if seq_len == self.config.match_len:
            return self.match_starts
        starts = self.items - window_offset(seq_len, self.config.window)
        return np.clip(starts, 0, len(self.frames) - seq_len)

    def rerank(self, query_frames: ArrayLike, q_starts: np.ndarray, candidates: np.ndarray,
               seq_len: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Re-rank ``candidates [M, K]`` (items, -1 = none) of query windows ``q_starts [M]`` over
        ``query_frames [Nq, D2]`` with the map's matcher; ``(scores [M, K], items [M, K])``, best first."""
        seq_len = seq_len or self.config.match_len
        return rerank_on_map(query_frames, self.frames, seq_len, q_starts, self.match_starts_for(seq_len),
                             candidates, self.config.method.matcher, str(self.device), window=self.config.window)

    def localize(self, shortlist_query: ArrayLike, query_frames: ArrayLike, q_starts: np.ndarray, top_k: int = 20,
                 k: int | None = None, exact: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """HVPR on the map (:func:`seqnet.matching.hvpr.hvpr`): shortlist ``top_k`` items, re-rank them, then the
        rest of the shortlist order up to ``k``. ``(scores [M, max(k, K)], items [M, max(k, K)])``."""
        _, ranked = self.search(shortlist_query, max(k or top_k, top_k), exact)
        head = min(top_k, ranked.shape[1])
        scores, items = self.rerank(query_frames, q_starts, ranked[:, :head])
        tail = np.full((len(ranked), ranked.shape[1] - head), np.inf, dtype=scores.dtype)
        return np.concatenate([scores, tail], axis=1), np.concatenate([items, ranked[:, head:]], axis=1)

    def describe(self, traverse: Traverse) -> QueryDescriptors:
        """The query items of ``traverse`` (windows as the map's) and their shortlist and frame descriptors."""
        return describe_traverse(traverse, self.config, self.models, self.device)

    def describe_info(self) -> str:
        """One line: size, descriptors, index."""
        c = self.config
        return (f"map {self.path}: {len(self.items)} items / {len(self.frames)} frames, {c.method.name} "
                f"(L={c.length}, L_m={c.match_len}, {c.window}), index {c.ann.kind}, {c.dtype}")


def read_meta(path: Path) -> dict[str, Any]:
    """``map.json`` of a map directory (:class:`MapError` when it is not one)."""
    if not path.is_dir():
        raise MapError(f"map directory not found: {path}" + (" (it is a file)" if path.exists() else ""))
    try:
        meta = json.loads((path / MAP_JSON).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise MapError(f"{path} is not a seqnet map: {MAP_JSON} is missing (hint: seqnet index build)") from None
    except (ValueError, UnicodeDecodeError) as e:
        raise MapError(f"{path / MAP_JSON}: not valid JSON ({e})") from None
    if not isinstance(meta, dict) or meta.get("format") != MAP_FORMAT:
        got = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
        raise MapError(f"{path / MAP_JSON}: format {got!r} is not {MAP_FORMAT!r}")
    return meta


def describe_traverse(traverse: Traverse, conf: MapConfig, models: dict[str, SeqNet],
                      device: torch.device) -> QueryDescriptors:
    """The items of ``traverse`` (L- and L_m-windows of ``conf`` inside their sequence) and their
    ``conf.shortlist`` descriptors ``[M, D1]``, and ``conf``'s frame descriptors of every frame ``[N, D2]``."""
    side = Side.of(traverse, conf.length, conf.match_len, conf.window)
    if len(side.items) == 0:
        raise MapError(f"no frame of {traverse.name} has a full window of L={conf.length} / L_m={conf.match_len} "
                       "inside its sequence; use shorter windows")
    out, ms = [], {}
    for kind, name in (("shortlist", conf.shortlist), ("frames", conf.frames_descriptor)):
        d, t0 = SEQUENCE_DESCRIPTORS[name], time.perf_counter()
        if kind == "frames":
            idx = window_indices(len(traverse), d.length(conf.length), conf.window, traverse.seq_bounds)
        else:
            idx = side.items[:, None] if d.single_frame else window_frames(side.starts, conf.length)
        out.append(describe_windows(traverse.descriptors, idx, d.window_fn(models), device=device, progress=name))
        ms[kind] = (time.perf_counter() - t0) * 1e3
    return QueryDescriptors(side, out[0], out[1], ms)
