"""Images matched to a timed log: the nearest sample in time, and why an image has none near it.

The one rule of seqnet's position logs (:mod:`seqnet.data.gps`) and ROS bags: each image takes the sample
nearest in time (the earlier one on a tie), refused beyond a tolerance, never given a far position.
"""

from __future__ import annotations

import datetime
from collections.abc import Callable

import numpy as np

from ..core.errors import DatasetError


def nearest_in_time(times: np.ndarray, query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(index [N], gap [N])``: the sample of the sorted ``times [S]`` nearest to each of ``query [N]`` (the
    earlier one on a tie) and its distance, in the unit of the times (the one rule of seqnet's position logs
    and ROS bags)."""
    right = np.clip(np.searchsorted(times, query), 0, len(times) - 1)
    left = np.clip(right - 1, 0, len(times) - 1)
    idx = np.where(np.abs(times[left] - query) <= np.abs(times[right] - query), left, right)
    return idx, np.abs(times[idx] - query)


def nearest_within(times: np.ndarray, query: np.ndarray, tolerance: float,
                   refusal: Callable[[np.ndarray, np.ndarray], str], scale: float = 1.0) -> np.ndarray:
    """:func:`nearest_in_time` indices; a query farther than ``tolerance`` (in the times' unit ÷ ``scale``) is a
    :class:`DatasetError` of ``refusal(bad, gap)``: the indices of all such queries ``[B]`` (ascending) and every
    query's gap ``[N]`` (÷ ``scale``)."""
    idx, gap = nearest_in_time(times, query)
    gap = gap / scale
    bad = np.flatnonzero(gap > tolerance)
    if bad.size:
        raise DatasetError(refusal(bad, gap))
    return idx


SMALL_MISS = 1.0  # seconds: a miss --max-time-gap may bridge (a few dropped samples); beyond it, trim or fix


def _when(t: float) -> str:
    """Epoch seconds as ``2015-02-03 08:45:10 UTC`` (plain seconds where they are no plausible date)."""
    if not 0 < t < 4.2e9:
        return f"{t:.3f} s"
    return datetime.datetime.fromtimestamp(t, datetime.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")


UNIT_FACTORS = (1e3, 1e6, 1e-3, 1e-6, 1e-9)  # the scalings of a time written in another unit than expected
UNITS = {-9: "nanoseconds", -6: "microseconds", -3: "milliseconds", 0: "seconds"}  # by power of ten of a second


def unit_factor(log_times: np.ndarray, image_times: np.ndarray) -> float | None:
    """The first of :data:`UNIT_FACTORS` that puts at least half of ``image_times [N]`` within the span of the
    sorted ``log_times [S]`` (image times written in another unit than the log's), else None."""
    t0, t1 = float(log_times[0]), float(log_times[-1])
    for f in UNIT_FACTORS:
        scaled = image_times * f
        if 2 * int(((scaled >= t0 - SMALL_MISS) & (scaled <= t1 + SMALL_MISS)).sum()) >= len(image_times):
            return f
    return None


def unit_hint(factor: float, unit: str | None) -> str:
    """What the image times ×``factor`` inside the log say: images named in another unit than ``unit`` (the
    unit the images' times are read in, e.g. ``"microseconds"``; None: not named by their time), and the fix."""
    power = round(np.log10(factor))
    times = f"×{factor:.0f}" if factor >= 1 else f"×{factor:g}"  # ×1000000, not ×1e+06
    expected = next((p for p, name in UNITS.items() if name == unit), None)
    written = UNITS.get(expected + power) if expected is not None else None
    if written is None:
        return (f"the image times {times} would lie within the log; hint: image and log clocks in different "
                "units? Give both in one unit")
    return (f"the image times {times} would lie within the log: they look like {written} against "
            f"a log in {unit}; hint: name the images by their time in {unit} (each name {times})")


def gap_hint(log_times: np.ndarray, image_times: np.ndarray, bad: np.ndarray, gaps: np.ndarray,
             other: str, unit: str | None = None) -> str:
    """The hint for images ``bad`` (indices into ``image_times [N]``) farther than the tolerance from every
    sample of the sorted ``log_times [S]``: when no image falls near it, the unit the image times look written in
    (:func:`unit_factor`; ``unit``: the one they are read in, see :func:`unit_hint`), else another run's log;
    else how many lie before / after the log or in its gaps; ``--max-time-gap`` only for a miss of at most
    :data:`SMALL_MISS`."""
    t0, t1 = float(log_times[0]), float(log_times[-1])
    worst = float(gaps[bad].max())
    if bad.size == len(image_times) and float(gaps.min()) > SMALL_MISS:
        when = f"the images are from {_when(float(image_times.min()))}, the log from {_when(t0)} to {_when(t1)}"
        factor = unit_factor(log_times, image_times)
        if factor is not None:
            return f"no image lies within the log ({when}), but {unit_hint(factor, unit)}"
        return f"no image lies within the log: {when}; hint: {other}? Give the log recorded with these images"
    tb = image_times[bad]
    parts = [f"{n} {w}" for n, w in ((int((tb < t0).sum()), "before the log's start"),
                                     (int((tb > t1).sum()), "after its end"),
                                     (int(((tb >= t0) & (tb <= t1)).sum()), "in gaps of the log (samples missing)"))
             if n]
    fix = "trim the images to the log" if (tb < t0).any() or (tb > t1).any() else "leave out the images in its gaps"
    if worst <= SMALL_MISS:
        need = np.ceil(round(worst * 100, 3)) / 100
        fix += f", or raise --max-time-gap to {need:g} (each such image then takes a sample that far off)"
    return f"of these, {', '.join(parts)}; hint: {fix}"
