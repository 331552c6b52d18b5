"""Positions at frame times: linear interpolation between the two track samples around each frame.

A frame before the first sample, after the last, or between two samples more than ``max_gap`` seconds apart (a
GPS outage) is outside the track: it gets no position, and the caller drops and counts it.
"""

from __future__ import annotations

import numpy as np

DEFAULT_MAX_GAP = 10.0  # seconds between two track samples a frame may be interpolated across
EDGE = 1e-3  # seconds: a frame this close beyond the track's first or last sample takes its position (clock rounding)


def at_times(times: np.ndarray, xy: np.ndarray, t: np.ndarray,
             max_gap: float = DEFAULT_MAX_GAP) -> tuple[np.ndarray, np.ndarray]:
    """``(xy [N, 2], inside [N] bool)``: the positions at the frame times ``t [N]`` on the track of sorted, distinct
    ``times [S]`` at ``xy [S, 2]``; rows of frames outside the track (``inside`` False) are NaN."""
    times, t = np.asarray(times, np.float64), np.asarray(t, np.float64)
    t = np.where((t < times[0]) & (t >= times[0] - EDGE), times[0], t)
    t = np.where((t > times[-1]) & (t <= times[-1] + EDGE), times[-1], t)
    right = np.searchsorted(times, t, side="left")
    exact = (right < len(times)) & (times[np.minimum(right, len(times) - 1)] == t)
    inside = exact | ((right > 0) & (right < len(times)))
    hi = np.clip(right, 1, max(len(times) - 1, 1))
    lo = hi - 1
    if len(times) > 1:
        inside &= exact | (times[hi] - times[lo] <= max_gap)
    else:
        hi = lo = np.zeros_like(right)
    span = np.where(times[hi] > times[lo], times[hi] - times[lo], 1.0)
    w = np.clip((t - times[lo]) / span, 0.0, 1.0)[:, None]
    out = (1 - w) * xy[lo] + w * xy[hi]
    out[exact] = xy[np.minimum(right, len(times) - 1)][exact]
    out[~inside] = np.nan
    return out, inside
