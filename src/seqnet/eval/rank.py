"""Ranking the query items with one method against a :class:`~seqnet.reference.base.Reference`, written once.

k-NN (``<descriptor>``), whole-map matching (``<frames>+<matcher>``) and HVPR (``hvpr-…``, fused
or not) on any reference — a dataset's traverse or a map — for the whole query traverse (the
evaluation) or for the newest causal window (the localiser, one item).
"""

from __future__ import annotations

import time
from typing import Protocol

import numpy as np
import torch

from ..matching.hvpr import hvpr_search
from ..reference.base import Reference
from .methods import FRAME_FEATURES, Method

Ranking = tuple[np.ndarray, np.ndarray, dict[str, float]]  # scores [M, k], items [M, k], timing ms


class Query(Protocol):
    """The query side: item descriptors ``items(name) [M, D1]``, frame descriptors ``frames(name) [Nq, D2]``,
    each item's L_m-window start ``match_starts [M]`` in them, and the time spent on each (ms)."""

    match_starts: np.ndarray

    def items(self, name: str) -> torch.Tensor: ...

    def frames(self, name: str) -> torch.Tensor: ...

    def time_ms(self, kind: str, name: str) -> float: ...


def rank(m: Method, query: Query, ref: Reference, k: int, top_k: int = 20, fuse: float = 0.0,
         exact: bool = False) -> Ranking:
    """``(scores [M, k'], items [M, k'], timing ms)`` of method ``m``: the k best reference items of every
    query item, best first (HVPR: ``k' = max(k, top_k)``; ``fuse``: λ of ``hvpr-fused``; ``exact``:
    shortlist without the reference's ANN index)."""
    ms = ref.prepare(m)
    frames = FRAME_FEATURES[m.frames] if m.frames else None
    if m.shortlist:
        q_items = query.items(m.shortlist)
        ms += query.time_ms("items", m.shortlist)
    if frames:
        q_frames = query.frames(frames)
        ms += query.time_ms("frames", frames)
    t0 = time.perf_counter()
    if m.kind == "knn":
        scores, items = ref.search(m.shortlist, q_items, k, exact)
        stage = "retrieval"
    elif m.kind == "match":
        scores, items = ref.match(frames, m.matcher, q_frames, query.match_starts, k)
        stage = "seqmatch"
    else:
        scores, items = hvpr_search(lambda n: ref.search(m.shortlist, q_items, n, exact),
                                    lambda c: ref.rerank(frames, m.matcher, q_frames, query.match_starts, c),
                                    ref.windows.match_len, top_k, k, fuse)
        stage = "hvpr"
    return scores, items, {"descriptors": ms, stage: (time.perf_counter() - t0) * 1e3}
