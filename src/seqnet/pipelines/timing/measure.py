"""Timing every method on one map: one query at a time (mean ± std) and in one batch (ms per query).

Descriptor comparisons per query (one comparison = one D-dimensional distance):

* single-image k-NN, S_1 / S_L k-NN: ``N_db`` (items for S_L);
* SeqMatch over the whole map, the paper's per-query formulation: ``N_db · L_m`` (each reference
  window's L_m distances, nothing reused between queries);
* SeqMatch over the whole map, ours (online ring buffer or a batch over a query traverse): ``N_db``
  per query (one new distance row per query frame, reused by the L_m windows that contain it) plus
  ``L_m · N_db`` additions;
* SeqMatch over the top K: ``K · L_m``; HVPR: the shortlist's (``N_db`` exact; the index's own count,
  read from FAISS, approximate) plus ``K · L_m``.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from ...maps import Map
from ...matching.seqmatch import seqmatch_topk
from ...metrics.recall import recall
from ...search.blocks import rows, topk_smallest
from ...search.knn import ExactIndex, finish_distances, sq_norms
from ...search.precision import compute_dtype
from .config import TimingConfig
from .queries import Queries
from .stream import OnlineSeqMatch


def sync(device: torch.device) -> None:
    """Wait for the GPU (timings of asynchronous kernels)."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def per_query(fn: Callable[[int], Any], n: int, warmup: int, device: torch.device) -> dict[str, float]:
    """Wall-clock milliseconds of ``fn(i)`` over ``i < n`` (mean, std), after ``warmup`` untimed calls, and
    the process CPU milliseconds per call (all threads: robust to other processes sharing the cores)."""
    for i in range(warmup):
        fn(i % n)
    times = []
    c0 = time.process_time()
    for i in range(n):
        sync(device)
        t0 = time.perf_counter()
        fn(i)
        sync(device)
        times.append((time.perf_counter() - t0) * 1e3)
    cpu = (time.process_time() - c0) * 1e3 / n
    return {"per_query_ms": statistics.fmean(times), "per_query_std_ms": statistics.pstdev(times),
            "per_query_cpu_ms": cpu}


def batch(fn: Callable[[], Any], repeats: int, device: torch.device) -> tuple[float, Any]:
    """Median milliseconds of ``fn()`` over ``repeats`` runs (after one untimed run), and its last result."""
    out = fn()
    times = []
    for _ in range(repeats):
        sync(device)
        t0 = time.perf_counter()
        out = fn()
        sync(device)
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times), out


def r_at_1(ranked: np.ndarray, truth: Any) -> float:
    """Recall@1 of a ranking ``[Q, K]``."""
    return round(float(recall(np.asarray(ranked), truth, (1,))["recall@1"]), 4)


@torch.no_grad()
def paper_seqmatch(search: ExactIndex, window: torch.Tensor, r_starts: torch.Tensor, k: int) -> torch.Tensor:
    """The paper's per-query SeqMatch over the whole map: the L_m distance rows of the query window
    ``[L_m, D]`` against every reference frame (nothing reused between queries), summed along each item's
    window; the ``k`` best items ``[k]``."""
    q_sq, dtype = sq_norms(window), compute_dtype(search.ref)
    dist = torch.cat([finish_distances(window @ rows(search.ref, a, b, search.device, dtype).T, q_sq, r_sq)
                      for (a, b), r_sq in zip(search.blocks, search.norms(dtype), strict=True)], dim=1)  # [L_m, N]
    scores = sum(dist[t, r_starts + t] for t in range(len(window)))
    return topk_smallest(scores[None], k)[1][0]


@torch.no_grad()
def describe_rows(qs: Queries, conf: TimingConfig, dev: torch.device) -> list[dict[str, Any]]:
    """S_1 (one frame) and S_L (one L-window) descriptor computation per query."""
    rows = []
    raw = qs.raw.to(dev)
    for role, name, x in (("s1", "describe_s1", lambda i: raw[i, -1:]), ("seqnet", "describe_sl",
                                                                         lambda i: raw[i : i + 1])):
        if role not in qs.models:
            continue
        model = qs.models[role].to(dev)
        pq = per_query(lambda i, m=model, x=x: m(x(i)), len(qs), conf.warmup, dev)
        ms, _ = batch(lambda m=model, role=role: m(raw[:, -1] if role == "s1" else raw), conf.repeats, dev)
        macs = model.out_dims * model.in_dims * model.w
        rows.append({"method": name, **pq, "batch_ms_per_query": ms / len(qs),
                     "comparisons": 0, "macs": macs})
    return rows


def knn_rows(mp: Map, qs: Queries, conf: TimingConfig, dev: torch.device) -> list[dict[str, Any]]:
    """Exact k-NN of single frames over the map's frames, and of the shortlist descriptor over its items."""
    k, rows = max(conf.top_ks), []
    single = np.ascontiguousarray(qs.frames[qs.starts(1)])
    for name, q, ref, truth in (("knn_single", single, mp.frames, qs.frame_truth),
                                ("knn_shortlist", qs.shortlist, mp.shortlist, qs.truth)):
        search = mp.exact_search(ref)
        pq = per_query(lambda i, q=q, s=search: s.search(q[i : i + 1], k), len(qs), conf.warmup, dev)
        ms, (_, ranked) = batch(lambda q=q, s=search: s.search(q, k), conf.repeats, dev)
        rows.append({"method": name, **pq, "batch_ms_per_query": ms / len(qs),
                     "comparisons": len(ref), "macs": len(ref) * ref.shape[1], "recall@1": r_at_1(ranked, truth)})
    return rows


def seqmatch_rows(mp: Map, qs: Queries, conf: TimingConfig, seq_len: int, dev: torch.device) -> list[dict[str, Any]]:
    """Whole-map SeqMatch: the paper's per-query formulation, ours online (ring buffer), ours in a batch."""
    k, n, d = max(conf.top_ks), len(mp.frames), mp.frames.shape[1]
    starts, r_starts = qs.starts(seq_len), mp.match_starts_for(seq_len)

    search, sel = mp.exact_search(mp.frames), torch.as_tensor(r_starts, device=dev)

    def paper(i: int) -> torch.Tensor:
        return paper_seqmatch(search, torch.from_numpy(qs.frames[starts[i] : starts[i] + seq_len]).to(dev), sel, k)

    pq = per_query(paper, len(qs), conf.warmup, dev)
    ranked = torch.stack([paper(i) for i in range(len(qs))]).cpu().numpy()
    rows = [{"method": "seqmatch_all_paper", **pq,
             "comparisons": n * seq_len, "macs": n * seq_len * d, "recall@1": r_at_1(ranked, qs.truth)}]
    ref = mp.frames if isinstance(mp.frames, torch.Tensor) else torch.from_numpy(np.asarray(mp.frames,
                                                                                               np.float32))
    online = OnlineSeqMatch(ref, seq_len, device=str(dev))
    for t in range(seq_len - 1):
        online.step(qs.stream[t])
    step = iter(range(seq_len - 1, len(qs.stream)))
    pq = per_query(lambda i: online.topk(online.step(qs.stream[next(step)]), k, sel),
                   min(len(qs), len(qs.stream) - seq_len + 1 - conf.warmup), conf.warmup, dev)
    ms, _ = batch(lambda: seqmatch_topk(qs.stream, mp.frames, seq_len, k, np.arange(len(qs)), r_starts,
                                        device=str(dev)), conf.repeats, dev)
    rows.append({"method": "seqmatch_all_ours", **pq,
                 "batch_ms_per_query": ms / len(qs), "comparisons": n, "macs": n * d})
    return rows
