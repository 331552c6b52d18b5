"""``seqnet eval --target-precision P``: a confidence threshold per method, calibrated on one split (val) with a
promise (:mod:`seqnet.metrics.calibration`), applied to the evaluated split: each method's results entry gets
``calibrated`` — the threshold (or why none), the fraction of queries accepted and the precision achieved, with
its Clopper–Pearson interval."""

from __future__ import annotations

from typing import Any

from ..core.errors import ConfigError
from ..core.log import logger
from ..data.traverse import Dataset
from ..metrics.calibration import apply_threshold, calibrate
from .evaluation import Evaluation
from .results import top1_correct


def check_calibration_split(ds: Dataset, calibrate_split: str, split: str) -> None:
    """The calibration split must exist and share no query with the evaluated one (a promise is made on held-out
    data)."""
    cal, ev = ds.ranges(calibrate_split), ds.ranges(split)
    if cal is None:
        valid = ", ".join(ds.splits) or "none"
        raise ConfigError(f"calibration split {calibrate_split!r} is not a split of dataset {ds.name!r} (its "
                          f"splits: {valid}) nor a range A:B; give --calibrate-split")
    (a, b), (c, d) = cal["query"], ev["query"] if ev is not None else (0, 0)
    if max(a, c) < min(b, d):
        raise ConfigError(f"the calibration split {calibrate_split!r} (queries {a}:{b}) overlaps the evaluated split "
                          f"{split!r} (queries {c}:{d}); calibrate on other queries (--calibrate-split)")


def top1(ev: Evaluation, name: str) -> tuple[Any, Any, Any]:
    """``(confidence [M], correct [M], has_positive [M])`` of method ``name``'s top-1 answers in ``ev``."""
    view = ev.view(name)
    correct = top1_correct(view.truth.without_soft(ev.retrieved[name], ev.scores[name])[0], view.truth)
    return ev.confidence[name], correct, view.truth.has_positive()


def add_calibration(ev: Evaluation, cal_ev: Evaluation, target: float, risk: float, calibrate_split: str) -> None:
    """Calibrate every method of ``ev`` on ``cal_ev`` (the same methods on the calibration split) and add, per
    method, ``calibrated`` (:func:`seqnet.metrics.calibration.apply_threshold` on ``ev``'s queries, with the
    calibration split named) to its results entry; one log line per method."""
    for name, entry in ev.results["methods"].items():
        conf, correct, _ = top1(cal_ev, name)
        cal = calibrate(conf, correct, target, risk)
        out = apply_threshold(cal, *top1(ev, name))
        out["calibration"]["split"] = calibrate_split
        entry["calibrated"] = out
        if cal.threshold is None:
            logger.debug("%s: no calibrated threshold (%s)", name, cal.reason)
        else:
            logger.debug("%s: confidence >= %.4g (calibrated on %s for precision >= %g, risk %g) accepts %.1f%%, "
                        "precision %s", name, cal.threshold, calibrate_split, target, risk,
                        100 * out["accepted_fraction"], out["precision"])
