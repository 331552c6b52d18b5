"""A confidence threshold whose precision holds on held-out data: calibrated on one split, applied to another.

:func:`seqnet.metrics.precision_recall.thresholds_for` gives the lowest threshold at which the *measured*
precision reaches a target; on held-out data it falls short (the val curve is noisy, and the threshold sits
where the val precision happened to be high). :func:`calibrate` instead gives a threshold with a promise:

    P( precision on new data, of the queries accepted at the threshold  <  target )  ≤  risk

for queries drawn from the distribution the calibration queries came from (i.i.d.; a route that changes
appearance between the splits is outside the promise: measure it, :func:`apply_threshold`).

The procedure is Learn-then-Test (Angelopoulos et al., 2021) with fixed-sequence testing. For a threshold t,
the null hypothesis ``H_t: precision(t) < target`` is rejected when the one-sided Clopper–Pearson lower
bound (level ``1 − risk``) of the precision of the calibration queries with confidence ≥ t reaches the target
(``k`` correct among ``n`` accepted: the binomial test of ``k ~ Bin(n, target)``). Thresholds are tested from
high to low, each at the full level ``risk``, and the sequence stops at the first one not rejected: the
family-wise error is at most ``risk``, so the lowest rejected threshold keeps the promise. The sequence
starts at the count :func:`start_count` (the fewest accepted queries at which the test survives one error),
chosen from the number of queries and the target only, never from the labels — starting where a single
early error would end it (zero errors allowed) declines far more often. A threshold that accepts ``n``
queries can only be certified when ``target**n ≤ risk`` (:func:`min_queries`: 299 queries at 0.99 and risk
0.05): with fewer calibration queries, or when no threshold passes, :func:`calibrate` declines and says why.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ..core.errors import ConfigError
from ..core.log import counted

RISK = 0.05  # the default probability that the promise fails


def check_target(target: float, risk: float) -> tuple[float, float]:
    """``(target, risk)`` as floats in (0, 1), the risk at most 0.5 (above, it is a confidence level given
    where the risk is meant: ``0.95`` for ``0.05``); a clear error otherwise."""
    for name, v in (("target precision", target), ("risk", risk)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 < float(v) < 1.0:
            raise ConfigError(f"{name} must be a number strictly between 0 and 1, got {v!r}")
    if float(risk) > 0.5:  # a confidence level given where the risk is meant: a promise that mostly fails
        raise ConfigError(f"--risk {float(risk):g}: the promise would fail with probability up to {float(risk):g} "
                          f"(the risk is the chance that it fails, not a confidence level); "
                          f"did you mean --risk {round(1.0 - float(risk), 12):g}?")
    return float(target), float(risk)


def clopper_pearson(k: np.ndarray | int, n: np.ndarray | int, alpha: float,
                    side: str = "lower") -> np.ndarray:
    """The exact (Clopper–Pearson) bound of a binomial proportion: ``k`` successes in ``n`` trials, one-sided
    at level ``1 − alpha`` (``side`` ``lower`` or ``upper``); elementwise. ``n = 0``: the trivial bound
    (0 or 1)."""
    from scipy.stats import beta

    k, n = np.asarray(k, dtype=np.float64), np.asarray(n, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        if side == "lower":
            out = np.where(k > 0, beta.ppf(alpha, np.maximum(k, 1), n - k + 1), 0.0)
        else:
            out = np.where(k < n, beta.ppf(1 - alpha, k + 1, np.maximum(n - k, 1)), 1.0)
    return np.where(n > 0, out, 0.0 if side == "lower" else 1.0)


def min_queries(target: float, risk: float, errors: int = 0) -> int:
    """The fewest accepted queries (with ``errors`` of them wrong) whose Clopper–Pearson lower bound at level
    ``1 − risk`` reaches ``target``: ``ceil(log(risk) / log(target))`` for ``errors = 0``."""
    target, risk = check_target(target, risk)
    n = max(errors + 1, math.ceil(math.log(risk) / math.log(target)))
    while clopper_pearson(n - errors, n, risk) < target:  # a few steps: the bound grows with n
        n += 1 if n < 64 else max(1, n // 64)
    while n > errors + 1 and clopper_pearson(n - 1 - errors, n - 1, risk) >= target:
        n -= 1
    return n


def start_count(n_queries: int, target: float, risk: float) -> int:
    """Where the fixed sequence starts, in accepted queries: the count at which one error is survivable when
    there are that many calibration queries, else the count that needs every accepted query correct."""
    one = min_queries(target, risk, errors=1)
    return one if n_queries >= one else min_queries(target, risk)


@dataclasses.dataclass(frozen=True)
class Calibration:
    """A calibrated threshold: accept a query when its confidence is ≥ ``threshold`` (None: declined, accept
    none; ``reason`` says why).

    Attributes:
        target, risk: the promise (precision ≥ target with probability ≥ 1 − risk).
        threshold: the confidence threshold, or None.
        queries: calibration queries; accepted / correct: of them at the threshold; lower_bound: the
            Clopper–Pearson lower bound of their precision (level 1 − risk); needed: the fewest accepted
            queries that could keep the promise at all (:func:`min_queries`).
    """

    target: float
    risk: float
    threshold: float | None
    queries: int
    accepted: int = 0
    correct: int = 0
    lower_bound: float | None = None
    needed: int = 0
    reason: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready, rounded."""
        d = dataclasses.asdict(self)
        for key in ("threshold", "lower_bound"):
            d[key] = None if d[key] is None else round(float(d[key]), 6)
        return d


def calibrate(confidence: np.ndarray, correct: np.ndarray, target: float, risk: float = RISK) -> Calibration:
    """The lowest confidence threshold whose precision is at least ``target`` with probability ≥ ``1 − risk``
    (module docstring), from the calibration queries' ``confidence [M]`` and top-1 ``correct [M]`` (a query
    without a correct reference counts as wrong when accepted). Declines (``threshold`` None) when the
    queries are too few or no threshold passes."""
    target, risk = check_target(target, risk)
    conf = np.asarray(confidence, dtype=np.float64)
    ok = np.asarray(correct, dtype=bool)
    if conf.shape != ok.shape or conf.ndim != 1:
        raise ConfigError(f"confidence and correct must be two [M] arrays, got {conf.shape} and {ok.shape}")
    m, needed = len(conf), min_queries(target, risk)
    base = {"target": target, "risk": risk, "queries": m, "needed": needed}
    cal_queries = counted(m, "calibration query", "calibration queries")
    if m < needed:
        return Calibration(threshold=None, **base,
                           reason=f"{cal_queries}; promising precision ≥ {target:g} with risk {risk:g} "
                                  f"needs at least {needed} accepted queries, all correct: calibrate on a larger "
                                  "split, lower the target or raise the risk")
    order = np.argsort(-conf, kind="stable")
    c, k = conf[order], np.cumsum(ok[order])
    n = np.arange(1, m + 1)
    last = np.r_[np.flatnonzero(np.diff(c) != 0), m - 1]  # each distinct threshold accepts its ties together
    last = last[n[last] >= start_count(m, target, risk)]
    if not last.size:  # every query ties above the start: one test, accepting all
        last = np.array([m - 1])
    lower = clopper_pearson(k[last], n[last], risk)
    failed = np.flatnonzero(lower < target)
    stop = int(failed[0]) if failed.size else len(last)  # the fixed sequence ends at its first non-rejection
    if stop == 0:
        i = last[0]
        errors = f"{int(n[i] - k[i])} error" + ("" if n[i] - k[i] == 1 else "s")
        return Calibration(threshold=None, **base, accepted=int(n[i]), correct=int(k[i]),
                           lower_bound=float(lower[0]),
                           reason=f"no threshold passes: the {int(n[i])} most confident of {cal_queries} "
                                  f"hold {errors} (precision lower bound {lower[0]:.3f} < "
                                  f"{target:g}); lower the target, raise the risk or calibrate on more queries")
    i = last[stop - 1]
    return Calibration(threshold=float(c[i]), **base, accepted=int(n[i]), correct=int(k[i]),
                       lower_bound=float(lower[stop - 1]))


def accepted(cal: Calibration, confidence: np.ndarray) -> np.ndarray:
    """``[M]`` bool: the queries the calibrated threshold accepts (none when it declined)."""
    conf = np.asarray(confidence, dtype=np.float64)
    return np.zeros(len(conf), bool) if cal.threshold is None else conf >= cal.threshold


def apply_threshold(cal: Calibration, confidence: np.ndarray, correct: np.ndarray,
                    has_positive: np.ndarray | None = None) -> dict[str, Any]:
    """What the calibrated threshold gives on other queries (``confidence [M]``, top-1 ``correct [M]``,
    ``has_positive [M]``): the accepted fraction, the achieved precision with its two-sided Clopper–Pearson
    interval (level ``1 − risk``; None when nothing is accepted), the recall kept, and whether the target was
    reached; JSON-ready, with the calibration."""
    conf = np.asarray(confidence, dtype=np.float64)
    ok = np.asarray(correct, dtype=bool)
    accept = accepted(cal, conf)
    n, k = int(accept.sum()), int(ok[accept].sum())
    has = int(np.asarray(has_positive, bool).sum()) if has_positive is not None else int(ok.sum())
    out: dict[str, Any] = {"calibration": cal.to_dict(), "queries": len(conf), "accepted": n,
                           "accepted_fraction": round(n / len(conf), 4) if len(conf) else 0.0, "correct": k,
                           "precision": round(k / n, 4) if n else None, "precision_interval": None,
                           "recall": round(k / has, 4) if has else 0.0}
    if n:
        lo = float(clopper_pearson(k, n, cal.risk / 2, "lower"))
        hi = float(clopper_pearson(k, n, cal.risk / 2, "upper"))
        out["precision_interval"] = [round(lo, 4), round(hi, 4)]
    out["target_met"] = None if not n else bool(k / n >= cal.target)
    return out

