"""Which frames to keep: one per ``1 / fps`` seconds of video, or one per ``metres`` travelled (vectorised).

Both keep the first frame of each bin (of time since the first frame, or of distance travelled along the
positions), so a video at 10 m spacing sampled every 20 m keeps every other frame.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError

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
    """``[K]`` indices of the frames at ``xy [N, 2]`` (in order) kept one per ``metres`` travelled along them."""
    if not metres > 0:
        raise ConfigError(f"--every-metres must be > 0, got {metres}")
    xy = np.asarray(xy, np.float64)
    travelled = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))]) if len(xy) else \
        np.zeros(0)
    return _first_of_bins(travelled, metres)
