"""Which frames to keep: one per ``1 / fps`` seconds of video, or one per ``metres`` travelled.

By time, the first frame of each bin of time since the first frame is kept (vectorised). By distance, a frame is
kept when ``metres`` or more of track lie between it and the last frame kept, and it lies that far from it in a
straight line too (both within :data:`METRES_SLACK`, for the chord of a curve), so GPS jitter at a standstill
(a red light: the fixes wander by a metre or two) keeps no frame, where summing the jitter as travel would keep
frame after frame of one place; a video at 10 m spacing sampled every 20 m keeps every other frame. (Jitter of
several metres from fix to fix can still reach ``metres`` now and then.) Each kept frame's search is vectorised
over a growing window of the frames after it.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError

METRES_SLACK = 0.005  # a frame this share short of ``metres`` from the last kept counts (a chord on a curve, or
# positions averaged over a curve: a little shorter than the road)
EPS = 1e-6  # of a bin: a frame this close below a bin's edge counts in it (times and distances in floats)


def _first_of_bins(values: np.ndarray, step: float) -> np.ndarray:
    bins = np.floor((values - values[0]) / step + EPS).astype(np.int64) if len(values) else values
    return np.flatnonzero(np.concatenate([[True], np.diff(bins) > 0])) if len(values) else np.zeros(0, np.int64)


def every_seconds(times: np.ndarray, fps: float) -> np.ndarray:
    """``[K]`` indices of the frames at sorted ``times [N]`` (seconds) kept at ``fps`` per second."""
    if not fps > 0:
        raise ConfigError(f"--fps must be > 0 frames per second, got {fps}")
    return _first_of_bins(np.asarray(times, np.float64), 1.0 / fps)


def every_metres(xy: np.ndarray, metres: float) -> np.ndarray:
    """``[K]`` indices of the frames at ``xy [N, 2]`` (in order) kept one per ``metres`` travelled: the first, then
    each that is at least ``metres`` (less :data:`METRES_SLACK`) from the last one kept, along the track and in a
    straight line."""
    if not metres > 0:
        raise ConfigError(f"--every-metres must be > 0, got {metres}")
    xy = np.asarray(xy, np.float64)
    if not len(xy):
        return np.zeros(0, np.int64)
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    keep, last = [0], 0
    while True:
        nxt = _first_beyond(xy, along, last, metres)
        if nxt is None:
            return np.asarray(keep, np.int64)
        keep.append(nxt)
        last = nxt


def _first_beyond(xy: np.ndarray, along: np.ndarray, i: int, metres: float) -> int | None:
    """The first index after ``i`` that lies ``metres`` or more (less :data:`METRES_SLACK`) from ``i`` along the
    track (``along [N]``: metres from the first frame) and in a straight line (``xy [N, 2]``); None when none
    does. Searched in windows that double in length."""
    start, width = i + 1, 64
    while start < len(xy):
        end = start + width
        d = np.linalg.norm(xy[start:end] - xy[i], axis=1)
        reach = metres * (1.0 - METRES_SLACK)
        hit = np.flatnonzero((along[start:end] - along[i] >= reach) & (d >= reach))
        if hit.size:
            return start + int(hit[0])
        start, width = start + width, width * 2
    return None
