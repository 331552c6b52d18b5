"""Timing the re-ranking of a shortlist and HVPR end to end (describe, shortlist, re-rank), exact or approximate."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import torch

from ...maps import Map
from ...matching.hvpr import order
from ...search.ann import build_index, shortlist_recall
from ...search.ann import search as ann_search
from .config import TimingConfig
from .measure import batch, per_query, r_at_1
from .queries import Queries


def build_indexes(mp: Map, conf: TimingConfig) -> tuple[dict[str, Any], dict[str, float]]:
    """An index of every kind of ``conf.indexes`` over the map's shortlist descriptors, and build seconds."""
    x = np.asarray(mp.shortlist, dtype=np.float32)
    indexes, seconds = {}, {}
    for kind in conf.indexes:
        t0 = time.perf_counter()
        indexes[kind] = build_index(x, conf.ann.merge(kind=kind))
        seconds[kind] = round(time.perf_counter() - t0, 3)
    return indexes, seconds


def ndis() -> int:
    """FAISS's count of distance computations since the last :func:`reset_ndis` (HNSW and IVF)."""
    import faiss

    return int(faiss.cvar.hnsw_stats.ndis + faiss.cvar.indexIVF_stats.ndis)


def reset_ndis() -> None:
    import faiss

    faiss.cvar.hnsw_stats.reset()
    faiss.cvar.indexIVF_stats.reset()


@torch.no_grad()
def describe(qs: Queries, idx: slice, dev: torch.device) -> None:
    """What a query costs before the search: S_L of its window and S_1 of its newest frame (when models are given)."""
    raw = qs.raw[idx].to(dev)
    if "seqnet" in qs.models:
        qs.models["seqnet"].to(dev)(raw)
    if "s1" in qs.models:
        qs.models["s1"].to(dev)(raw[:, -1])


def hvpr_rows(mp: Map, qs: Queries, conf: TimingConfig, seq_len: int, top_k: int, indexes: dict[str, Any],
              dev: torch.device) -> list[dict[str, Any]]:
    """Re-ranking the exact top K alone, and HVPR end to end with the exact shortlist and with each index."""
    starts, q, n = qs.starts(seq_len), len(qs), len(mp.shortlist)
    exact = mp.search(mp.config.shortlist, qs.shortlist, top_k, exact=True)[1]

    def rerank(i: slice, cand: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return order(mp.pair_scores(qs.frames, starts[i], cand, seq_len), cand, seq_len)

    pq = per_query(lambda i: rerank(slice(i, i + 1), exact[i : i + 1]), q, conf.warmup, dev)
    ms, _ = batch(lambda: rerank(slice(None), exact), conf.repeats, dev)
    rows = [{"method": "seqmatch_topk", **pq, "batch_ms_per_query": ms / q,
             "comparisons": top_k * seq_len, "macs": top_k * seq_len * mp.frames.shape[1]}]
    searches = {"exact": lambda i: mp.search(mp.config.shortlist, qs.shortlist[i], top_k, exact=True)[1]}
    for kind, index in indexes.items():
        searches[kind] = lambda i, index=index: ann_search(index, qs.shortlist[i], top_k)[1]
    for name, search in searches.items():
        def e2e(i: slice, search=search) -> np.ndarray:
            describe(qs, i, dev)
            return rerank(i, search(i))[1]

        pq = per_query(lambda i, e2e=e2e: e2e(slice(i, i + 1)), q, conf.warmup, dev)
        reset_ndis()
        ms, ranked = batch(lambda e2e=e2e: e2e(slice(None)), conf.repeats, dev)
        found = ndis() / (q * (conf.repeats + 1)) if name != "exact" else n
        row = {"method": f"hvpr_{name}", **pq, "batch_ms_per_query": ms / q,
               "comparisons": round(found + top_k * seq_len, 1), "macs": round(found * mp.shortlist.shape[1] + top_k
                                                                               * seq_len * mp.frames.shape[1]),
               "recall@1": r_at_1(ranked, qs.truth),
               "shortlist_recall": round(shortlist_recall(search(slice(None)), exact), 4)}
        rows.append(row)
    return rows


def float16_recall(mp: Map, qs: Queries, seq_len: int, top_k: int) -> dict[str, float]:
    """R@1 of exact HVPR with the map's descriptors as stored and rounded to float16 (the same map)."""
    out = {}
    for dtype in ("float32", "float16"):
        sl = np.asarray(mp.shortlist).astype(dtype, copy=False)
        cand = _with(mp, sl).search(mp.config.shortlist, qs.shortlist, top_k, exact=True)[1]
        frames = np.asarray(mp.frames).astype(dtype, copy=False)
        scores = _with(mp, sl, frames).pair_scores(qs.frames, qs.starts(seq_len), cand, seq_len)
        ranked = order(scores, cand, seq_len)[1]
        out[dtype] = r_at_1(ranked, qs.truth)
    return out


def _with(mp: Map, shortlist: np.ndarray, frames: np.ndarray | None = None) -> Map:
    """A shallow copy of ``mp`` with other descriptor arrays."""
    import copy

    other = copy.copy(mp)
    other.shortlist = shortlist
    if frames is not None:
        other.frames = frames
    return other
