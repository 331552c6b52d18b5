"""Ranking the query items with one method against a :class:`~seqnet.methods.protocol.Reference`, written once.

k-NN (``<descriptor>``), whole-map matching (``<frames>+<matcher>``) and HVPR (``hvpr-…``, fused
or not) on any reference — a dataset's traverse or a map — for the whole query traverse (the
evaluation) or for the newest causal window (the localiser, one item).
"""

from __future__ import annotations

import time
from typing import Protocol

import numpy as np

from ..core.lazy import lazy_module
from ..matching.hvpr import PairScores, Search, hvpr_search
from ..matching.pairs import item_scores_from_distances, nearest_items, pick_strategy
from ..matching.registry import SEQUENCE_MATCHERS
from ..sequence.descriptors import SEQUENCE_DESCRIPTORS
from .grammar import FRAME_FEATURES, Method, needs
from .protocol import Reference

torch = lazy_module("torch")

Ranking = tuple[np.ndarray, np.ndarray, dict[str, float]]  # scores [M, k], items [M, k], timing ms


class Query(Protocol):
    """The query side: item descriptors ``items(name) [M, D1]``, frame descriptors ``frames(name) [Nq, D2]``,
    each item's L_m-window start ``match_starts [M]`` and frame ``items_index [M]`` in them, the frames'
    sequence ranges ``seq_bounds [Nq, 2]`` (None: one sequence), and the time spent on a set of them, each
    counted once (ms)."""

    match_starts: np.ndarray
    items_index: np.ndarray
    seq_bounds: np.ndarray | None

    def items(self, name: str) -> torch.Tensor: ...

    def frames(self, name: str) -> torch.Tensor: ...

    def cost_ms(self, keys: list[tuple[str, str]]) -> float: ...


def rank(m: Method, query: Query, ref: Reference, k: int, top_k: int = 20, fuse: float = 0.0,
         exact: bool = False) -> Ranking:
    """``(scores [M, k'], items [M, k'], timing ms)`` of method ``m``: the k best reference items of every
    query item, best first (HVPR: ``k' = max(k, top_k)``; ``fuse``: λ of ``hvpr-fused``; ``exact``:
    shortlist without the reference's ANN index)."""
    ms = ref.prepare(m) + query.cost_ms(needs(m))  # each descriptor's time once
    frames = FRAME_FEATURES[m.frames] if m.frames else None
    if m.shortlist:
        q_items = query.items(m.shortlist)
    if frames:
        q_frames = query.frames(frames)
    t0 = time.perf_counter()
    if m.kind == "knn":
        scores, items = ref.search(m.shortlist, q_items, k, exact)
        stage = "retrieval"
    elif m.kind == "match":
        scores, items = ref.match(frames, m.matcher, q_frames, query.match_starts, k)
        stage = "seqmatch"
    else:
        search, pairs = _hvpr_parts(m, query, ref, q_items, q_frames, exact, top_k)
        scores, items = hvpr_search(search, pairs, ref.windows.match_len, top_k, k, fuse)
        stage = "hvpr"
    return scores, items, {"descriptors": ms, stage: (time.perf_counter() - t0) * 1e3}


def _hvpr_parts(m: Method, query: Query, ref: Reference, q_items: torch.Tensor, q_frames: torch.Tensor,
                exact: bool, top_k: int) -> tuple[Search, PairScores]:
    """HVPR's shortlist search and re-ranker. When the shortlist is the frames' own descriptor and the
    re-ranking would compute whole distance rows anyway (:func:`seqnet.matching.pairs.pick_strategy`),
    both read one matrix of frame distances, computed once (``ref.shared_distances``)."""
    frames, n_ref = FRAME_FEATURES[m.frames], len(ref.positions)
    shared = (m.shortlist == frames and SEQUENCE_MATCHERS[m.matcher].diagonal
              and SEQUENCE_DESCRIPTORS[frames].single_frame
              and pick_strategy(len(query.match_starts), top_k, ref.windows.match_len, n_ref) == "rows")
    dist = ref.shared_distances(frames, q_frames) if shared else None
    if dist is None:
        return (lambda n: ref.search(m.shortlist, q_items, n, exact),
                lambda c: ref.rerank(frames, m.matcher, q_frames, query.match_starts, c))
    q_starts = torch.as_tensor(query.match_starts, device=dist.device)
    r_starts = torch.as_tensor(ref.match_starts, device=dist.device)

    def search(n: int) -> tuple[np.ndarray, np.ndarray]:
        return nearest_items(dist, query.items_index, ref.items, n)

    def pairs(cand: np.ndarray) -> torch.Tensor:
        return item_scores_from_distances(dist, ref.windows.match_len, q_starts, r_starts, cand,
                                          SEQUENCE_MATCHERS[m.matcher].reverse)

    return search, pairs
