"""Confidence of a localisation and the precision–recall curve it gives.

A robot must decide whether to trust its top-1 match. The *ratio confidence* of a query compares
the score of its best reference with the best score among the retrieved references farther than
the localisation radius from that best one (a second, different place): lower scores are better, and

    confidence = (s_other − s_best) / max(|s_best|, |s_other|, s_other − s_best)   in [0, 1]

which is the classic ratio test ``1 − s_best / s_other`` for distances (scores ≥ 0) and stays defined for
scores of any sign and scale (a negated similarity matrix, ``--similarity``): scaling the scores does not
change it, and it grows with the margin between the two places; 0 when the other place scores as well. When no
other place is among the retrieved (all within the radius of the best: a small ``--k``, or a dense reference), the
last retrieved score stands in for ``s_other``: any other place ranks after it, so this is a lower bound of the
confidence, never 1 from one place alone (it was 1: ``--k 2`` gave wrong answers confidence 1.000, hunt 5); one
retrieved reference gives 0. Thresholding it trades recall for
precision: :func:`precision_recall` gives the curve over all thresholds (top-1 correctness, recall
relative to the queries that have a correct reference), :func:`pr_summary` its area (average
precision) and the recall at 100 % precision, and :func:`thresholds_for` the threshold that reaches a
given precision (what a threshold means: calibrate it on a val split).
"""

from __future__ import annotations

import numpy as np


def ratio_confidence(scores: np.ndarray, ranked: np.ndarray, r_pos: np.ndarray, radius: float) -> np.ndarray:
    """``[M]`` confidence of each query's top-1 from its ranked ``scores [M, K]`` / items ``ranked [M, K]``.

    ``r_pos [R, P]`` are the reference item positions; items within ``radius`` of the top-1 count as
    the same place. Non-finite scores (not scored, e.g. beyond an HVPR shortlist) are ignored. Without another
    place among them, the last scored one bounds it (a lower bound of the confidence; see the module).
    """
    scores, ranked = np.asarray(scores, dtype=np.float64), np.asarray(ranked, dtype=np.int64)
    m = len(ranked)
    if ranked.shape[1] == 0:
        return np.zeros(m)
    pos = np.asarray(r_pos, dtype=np.float64)
    pos = pos[:, None] if pos.ndim == 1 else pos
    cand = pos[ranked.clip(0)]  # [M, K, P]
    far = np.sqrt(np.square(cand - cand[:, :1]).sum(axis=-1)) > radius  # [M, K]: another place than the top-1
    scored = np.isfinite(scores) & (ranked >= 0)
    other = np.where(far & scored, scores, np.inf).min(axis=1)
    last = np.where(scored, scores, -np.inf).max(axis=1)  # any other place ranks after the last one scored
    other = np.where(np.isfinite(other), other, last)
    conf = np.zeros(m)
    some = np.isfinite(other) & np.isfinite(scores[:, 0])
    best, second = scores[some, 0], other[some]
    den = np.maximum(np.maximum(np.abs(best), np.abs(second)), second - best)
    with np.errstate(invalid="ignore", divide="ignore"):
        conf[some] = np.where(den > 0, (second - best) / np.where(den > 0, den, 1.0), 0.0)
    conf[np.isnan(conf)] = 0.0
    return np.clip(conf, 0.0, 1.0)


def precision_recall(confidence: np.ndarray, correct: np.ndarray,
                     has_positive: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(precision [T], recall [T], thresholds [T])`` of accepting the queries with confidence ≥ threshold.

    ``correct [M]``: the top-1 is a correct reference; ``has_positive [M]``: the query has one (the
    recall denominator). Queries without a correct reference count as false positives when accepted.
    Thresholds are the distinct confidences, descending; ties are accepted together.
    """
    conf = np.asarray(confidence, dtype=np.float64)
    if not len(conf):
        return np.zeros(0), np.zeros(0), np.zeros(0)
    order = np.argsort(-conf, kind="stable")
    tp = np.cumsum(np.asarray(correct, bool)[order])
    n = np.arange(1, len(conf) + 1)
    last = np.r_[np.flatnonzero(np.diff(conf[order]) != 0), len(conf) - 1]  # last index of each tie group
    total = max(int(np.asarray(has_positive, bool).sum()), 1)
    return tp[last] / n[last], tp[last] / total, conf[order][last]


def pr_summary(precision: np.ndarray, recall: np.ndarray) -> dict[str, float]:
    """Area under the PR curve (average precision: Σ precision·Δrecall) and the recall at 100 % precision."""
    if len(recall) == 0:
        return {"auc": float("nan"), "recall@100p": float("nan")}
    delta = np.diff(np.r_[0.0, recall])
    perfect = recall[precision >= 1.0]
    return {"auc": float(np.sum(precision * delta)), "recall@100p": float(perfect.max()) if perfect.size else 0.0}


def curve_points(precision: np.ndarray, recall: np.ndarray, max_points: int = 200) -> dict[str, list[float]]:
    """The PR curve as at most ``max_points`` evenly spaced points of it (first and last kept), rounded to
    4 decimals, for ``results.json`` and plots: ``{"precision": [...], "recall": [...]}``."""
    n = len(recall)
    keep = np.linspace(0, n - 1, min(n, max_points)).round().astype(np.int64)
    keep = keep[np.r_[True, keep[1:] != keep[:-1]]] if n else keep  # sorted: np.unique without loading numpy.ma
    return {"precision": [round(float(p), 4) for p in np.asarray(precision)[keep]],
            "recall": [round(float(r), 4) for r in np.asarray(recall)[keep]]}


PRECISION_TARGETS = (0.9, 0.95, 0.99)


def thresholds_for(precision: np.ndarray, recall: np.ndarray, thresholds: np.ndarray,
                   targets: tuple[float, ...] = PRECISION_TARGETS) -> dict[str, dict[str, float] | None]:
    """What a confidence threshold means on this evaluation: for each target precision P, the lowest
    threshold accepting only queries at precision >= P and the recall it keeps (None: no threshold reaches
    P). Measured on a val split, it is the threshold to use online (``seqnet eval --split val``)."""
    out: dict[str, dict[str, float] | None] = {}
    for target in targets:
        ok = np.flatnonzero(np.asarray(precision) >= target)
        i = int(ok.max()) if ok.size else None  # the lowest threshold (the curve runs high to low) still at P
        out[f"{target:g}"] = None if i is None else {"confidence": round(float(thresholds[i]), 6),
                                                      "recall": round(float(recall[i]), 4)}
    return out
