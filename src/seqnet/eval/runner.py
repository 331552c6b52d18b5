"""The one evaluation loop (:func:`run`): every method ranked against a reference, scored (Recall@K, PR, AUC) and
timed, with the one-time start-up costs paid before any method is timed (:func:`warm_up`) and what an HVPR's
shortlist holds (:func:`shortlist_cap`); the dataset, map and matrix evaluations all run it."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ..core.lazy import lazy_module
from ..core.log import logger
from ..methods.grammar import Method
from ..methods.protocol import Reference
from ..methods.rank import Query, rank
from ..metrics.consistency import QueryOrder
from ..metrics.recall import GroundTruth
from ..sequence.described import Described
from ..sequence.windows import Windows
from .config import EvalConfig
from .evaluation import Evaluation, no_window_reason
from .results import method_results

torch = lazy_module("torch")


def run(methods: Sequence[Method], query: Described, ref: Reference, truth: GroundTruth, conf: EvalConfig,
        n_frames: int, info: Callable[[Method], dict[str, Any]],
        extra: Callable[[Method, np.ndarray], dict[str, Any]] | None = None,
        windows: Windows | None = None, with_torch: bool = True) -> Evaluation:
    """The one evaluation loop: rank every method against ``ref`` (:func:`seqnet.methods.rank.rank`), score
    it (Recall@K, PR, AUC) and time it; ``info(m)`` describes the method, ``extra(m, items)`` adds entries
    (a map's shortlist recall). ``n_frames``: query frames, for the count left out (no full window) under
    ``windows`` (default ``conf.windows``), and why. ``with_torch``: the methods run in torch, which is loaded and
    warmed up before the first is timed (:func:`warm_up`)."""
    windows = windows or conf.windows
    left_out = int(n_frames - len(truth.q_pos))
    why = {"no_full_window_reason": no_window_reason(windows, query.seq_bounds is not None)} if left_out else {}
    results: dict[str, Any] = {}
    retrieved, scores, confidence = {}, {}, {}
    warm_up(with_torch)
    for m in methods:
        ref.check_method(m)
        scores[m.name], retrieved[m.name], timing = rank(m, query, ref, max(conf.ks), conf.shortlist_size(m),
                                                         conf.weight(m))
        timing["total"] = sum(timing.values())
        entry, confidence[m.name] = method_results(scores[m.name], retrieved[m.name], truth, conf.ks,
                                                   conf.extra_radii, conf.recall_denominator,
                                                   query_order(conf, query, ref.items, windows))
        entry.update(extra(m, retrieved[m.name]) if extra else {}, no_full_window=left_out, **why,
                     timing_ms={k: round(v, 3) for k, v in timing.items()}, method=info(m),
                     **shortlist_cap(m, retrieved[m.name], truth, conf))
        results[m.name] = entry
        logger.debug("%s: R@1 %.3f (%d queries)", m.name, entry.get("recall@1", float("nan")), entry["queries"])
    return Evaluation({"methods": results}, retrieved, scores, truth, query.items_index, ref.items, confidence,
                      windows=windows)


def warm_up(with_torch: bool) -> None:
    """Pay the one-time start-up costs before any method is timed, so each method's time is its own: the lazy
    imports (NumPy loads its masked arrays on a first ``np.unique``; torch, ``with_torch``, 1–4 s) and torch's first
    kernels. Charged to whichever method came first, they made it look up to 300 times slower."""
    np.unique(np.zeros(2))
    if with_torch:
        x = torch.zeros((4, 4))
        torch.topk(x @ x.T, 2, dim=1)


def shortlist_cap(m: Method, retrieved: np.ndarray, truth: GroundTruth, conf: EvalConfig) -> dict[str, Any]:
    """``{"shortlist_recall": {"k": K, "recall": r}}`` of an HVPR ``m``: the share of the counted queries whose
    shortlist of K (the first K of ``retrieved [M, ≥K]``, which the re-ranking only reorders) holds a correct
    reference, the most its R@1 can reach; empty for other methods, or when fewer than K were retrieved."""
    k = conf.shortlist_size(m) if m.kind == "hvpr" else 0
    if not k or retrieved.shape[1] < k or not len(retrieved):
        return {}
    keep = truth.has_positive() if conf.recall_denominator == "positives" else np.ones(len(retrieved), bool)
    if not keep.any():
        return {}
    held = truth.hits(retrieved[:, :k])[keep].any(axis=1)
    return {"shortlist_recall": {"k": int(k), "recall": float(held.mean())}}


def query_order(conf: EvalConfig, query: Query, r_items: np.ndarray, windows: Windows) -> QueryOrder | None:
    """Where the evaluated items lie, for the sequence confidence (``conf.confidence == "sequence"``; else None):
    neighbours within L query frames (the L before with causal windows), in the query's own sequence."""
    if conf.confidence != "sequence":
        return None
    q_items = np.asarray(query.items_index)
    bounds = query.seq_bounds
    return QueryOrder(q_items, np.asarray(r_items), conf.seq_len or windows.seq_len, windows.mode == "causal",
                      None if bounds is None else np.asarray(bounds)[q_items, 0])
