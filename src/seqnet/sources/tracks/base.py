"""The one form of a track: :class:`Track`, times and coordinates, and :func:`track_of` building it."""

from __future__ import annotations

import dataclasses

import numpy as np

from ...core.errors import DatasetError
from ...security.text import shown

MAX_TRACK_BYTES = 1 << 28  # a GPX / NMEA / CSV track file larger than this is refused before it is read


@dataclasses.dataclass(frozen=True)
class Track:
    """A track: ``times [S]`` seconds, sorted and distinct; ``coords [S, 2]``.

    Attributes:
        times: seconds since the epoch (UTC) when ``absolute``; else seconds since the video's start. An NMEA
            track of GGA sentences only (times of day, no date: ``dated`` False) counts from its day's midnight.
        coords: latitude, longitude (degrees) when ``geographic``; else x, y (metres, in the track's own frame).
        source: the file (for messages).
    """

    times: np.ndarray
    coords: np.ndarray
    absolute: bool
    geographic: bool
    source: str
    dated: bool = True


def track_of(times: list[float], coords: list[tuple[float, float]], source: str, **kw: bool) -> Track:
    """A :class:`Track` of the samples read (any order; a repeated time keeps its first sample); a track with no
    sample, or a coordinate out of range, is a :class:`DatasetError`."""
    t = np.asarray(times, np.float64)
    c = np.asarray(coords, np.float64).reshape(-1, 2)
    if not len(t):
        raise DatasetError(f"{shown(source)}: no position with a time in the track")
    if not (np.isfinite(t).all() and np.isfinite(c).all()):
        raise DatasetError(f"{shown(source)}: a time or position is not a finite number")
    if kw.get("geographic", True):
        bad = np.flatnonzero((np.abs(c[:, 0]) > 90) | (np.abs(c[:, 1]) > 180))
        if bad.size:
            raise DatasetError(f"{shown(source)}: sample {int(bad[0])}: latitude {c[bad[0], 0]:g}, longitude "
                               f"{c[bad[0], 1]:g} out of range")
    order = np.argsort(t, kind="stable")
    t, c = t[order], c[order]
    first = np.concatenate([[True], np.diff(t) > 0])
    return Track(times=t[first], coords=c[first], source=source, **{"absolute": True, "geographic": True, **kw})
