"""``seqnet eval --target-precision P``: a confidence threshold per method, calibrated on one split (val) with a
promise (:mod:`seqnet.metrics.calibration`), applied to the evaluated split: each method's results entry gets
``calibrated`` — the threshold (or why none), the fraction of queries accepted and the precision achieved, with
its Clopper–Pearson interval."""

from __future__ import annotations

from typing import Any

from ..core.errors import ConfigError, WindowsTooLongError
from ..core.log import counted, logger
from ..data.traverse import Dataset
from ..methods.checks import named_test_split
from ..metrics.calibration import apply_threshold, calibrate
from ..security.text import shown
from .evaluation import Evaluation
from .results import top1_correct


def check_calibration_split(ds: Dataset, calibrate_split: str, split: str) -> None:
    """The calibration split must exist and share no query with the evaluated one (a promise is made on held-out
    data)."""
    cal, ev = ds.ranges(calibrate_split), ds.ranges(split)
    if cal is None:
        valid = ", ".join(ds.splits) or "none"
        whole = "" if ds.splits else (" (a split of a dataset has none: evaluate the whole dataset, whose val split "
                                      "it calibrates on, with split='test')")
        raise ConfigError(f"calibration split {calibrate_split!r} is not a split of dataset {ds.name!r} (its "
                          f"splits: {valid}) nor a range A:B; give --calibrate-split (calibrate_split= in Python)"
                          f"{whole or unsplit_hint(ds)}")
    (a, b), (c, d) = cal["query"], ev["query"] if ev is not None else (0, 0)
    if max(a, c) < min(b, d):
        raise ConfigError(f"the calibration split {calibrate_split!r} (queries {a}:{b}) overlaps the evaluated split "
                          f"{split!r} (queries {c}:{d}); calibrate on other queries (--calibrate-split; "
                          "EvalConfig(calibrate_split=...) in Python)")


FREE_MIN = 20  # queries: a range in no split shorter than this is not offered to calibrate on


def unsplit_hint(ds: Dataset) -> str:
    """`` (e.g. --calibrate-split 200:240: 40 queries in no split)``: the longest query range of ``ds`` in none of
    its splits (so neither trained, chosen nor evaluated on), when it has :data:`FREE_MIN` or more; else ""."""
    n = len(ds.query)
    used = sorted(tuple(ds.ranges(name)["query"]) for name in ds.splits)
    edges, free = [*used, (n, n)], []
    start = 0
    for a, b in edges:
        if a - start >= FREE_MIN:
            free.append((a - start, start, a))
        start = max(start, b)
    if not free:
        return ""
    _, a, b = max(free)
    return f" (e.g. --calibrate-split {a}:{b}: {b - a} queries in no split)"


def calibration_failed(ds: Dataset, calibrate_split: str, e: ConfigError) -> ConfigError:
    """The error of evaluating the calibration split, saying that split's size; when it is too short for the
    windows (:func:`seqnet.methods.checks.check_windows_fit`), the fix is a longer calibration split, not a longer
    evaluated one, or no calibration."""
    a, b = ds.ranges(calibrate_split)["query"]
    said = f"calibrating on {calibrate_split!r} (queries {a}:{b}, {b - a} frames): {e}"
    if isinstance(e, WindowsTooLongError):
        said += (f" (the calibration split is the short one: give --calibrate-split A:B, longer than {b - a} frames "
                 "and apart from the evaluated queries, or leave out --target-precision to evaluate without it)")
    return ConfigError(said)


def calibration_on_test(ds: Dataset, calibrate_split: str | None, split: str) -> str | None:
    """One line when the calibration split is the test split of ``ds`` or holds some of its queries: the threshold a
    robot will use is then fitted on the held-out queries, and every test figure with it is optimistic (as
    ``train --val-split test`` says); the hint names a split apart from the test and the evaluated (``split``)
    queries. None otherwise (and for no calibration split)."""
    if calibrate_split is None:
        return None
    test, cal = named_test_split(ds.splits), ds.ranges(calibrate_split)
    if test is None or cal is None:
        return None
    (a, b), (ta, tb) = cal["query"], ds.ranges(test)["query"]
    both = max(0, min(b, tb) - max(a, ta))
    if not both:
        return None
    if calibrate_split.lower() == "test":
        head = f"--calibrate-split {shown(calibrate_split)}: calibrating the threshold on the test split"
    else:
        where = calibrate_split if calibrate_split == f"{a}:{b}" else f"{shown(calibrate_split)} (queries {a}:{b})"
        head = (f"--calibrate-split {where} holds {both} of the {counted(tb - ta, 'query', 'queries')} of the test "
                f"split {test!r} ({ta}:{tb}): calibrating the threshold on them")
    return f"{head} makes every test figure with it optimistic (hint: {_apart_hint(ds, (ta, tb), split)})"


def _apart_hint(ds: Dataset, test: tuple[int, int], split: str) -> str:
    """``--calibrate-split S`` with S a split apart from the ``test`` queries and the evaluated split (val first,
    never a train split), else a range to give."""
    ev = ds.ranges(split)
    avoid = [test, *([tuple(ev["query"])] if ev is not None else [])]
    for name in sorted(ds.splits, key=lambda s: s.lower() != "val"):
        a, b = ds.ranges(name)["query"]
        if name.lower() not in ("test", "train") and all(min(b, d) <= max(a, c) for c, d in avoid):
            return f"--calibrate-split {name}"
    spans = " and ".join(f"{c}:{d}" for c, d in avoid)
    return f"--calibrate-split A:B, a range apart from {spans}"


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
