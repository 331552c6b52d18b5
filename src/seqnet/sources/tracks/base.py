"""The one form of a track: :class:`Track`, times and coordinates, and :func:`track_of` building it."""

from __future__ import annotations

import dataclasses
import datetime

import numpy as np

from ...core.errors import DatasetError
from ...core.log import logger
from ...security.text import shown

MAX_TRACK_BYTES = 1 << 28  # a GPX / NMEA / CSV track file larger than this is refused before it is read
EPOCH_UNITS = ((1.0, "seconds"), (1e3, "milliseconds"), (1e6, "microseconds"), (1e9, "nanoseconds"))
EPOCH_SPAN = (1e9, 1e10)  # Unix epoch seconds of 2001-09-09 .. 2286-11-20: numbers this large are no video's seconds


def epoch_unit(times: np.ndarray) -> tuple[float, str] | None:
    """``(per second, name)`` of numeric track times ``[S]`` that are all Unix epoch times in one of
    :data:`EPOCH_UNITS` (seconds around 1.7e9, milliseconds 1.7e12, microseconds 1.7e15, nanoseconds 1.7e18);
    None for any other numbers (seconds since a video's start)."""
    t = np.asarray(times, np.float64)
    if not len(t) or not np.isfinite(t).all():
        return None
    lo, hi = float(t.min()), float(t.max())
    return next(((k, name) for k, name in EPOCH_UNITS if EPOCH_SPAN[0] <= lo / k and hi / k < EPOCH_SPAN[1]), None)


@dataclasses.dataclass(frozen=True)
class Track:
    """A track: ``times [S]`` seconds, sorted and distinct; ``coords [S, 2]``.

    Attributes:
        times: seconds since the epoch (UTC) when ``absolute``; else seconds since the video's start. An NMEA
            track of GGA sentences only (times of day, no date: ``dated`` False) counts from its day's midnight.
        coords: latitude, longitude (degrees) when ``geographic``; else x, y (metres, in the track's own frame).
        source: the file (for messages).
        epoch: how numbers read as Unix epoch times were written (``milliseconds``: :data:`EPOCH_UNITS`), for
            messages; "" for any other track.
        zoned: False when ISO-8601 times were written without a zone (read as UTC; local time is a common slip).
    """

    times: np.ndarray
    coords: np.ndarray
    absolute: bool
    geographic: bool
    source: str
    dated: bool = True
    epoch: str = ""
    zoned: bool = True


def track_of(times: list[float], coords: list[tuple[float, float]], source: str, **kw: bool) -> Track:
    """A :class:`Track` of the samples read (any order; a repeated time keeps its first sample, warned when another
    lies elsewhere, refused far away: :func:`_check_repeats`); a track with no
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
    _check_repeats(t, c, first, source, kw.get("geographic", True), kw.get("absolute", True))
    return Track(times=t[first], coords=c[first], source=source, **{"absolute": True, "geographic": True, **kw})


REPEAT_WARN = 5.0  # metres between two fixes of one time: warned (one of them is used)
REPEAT_REFUSE = 1000.0  # metres: refused (two receivers merged, or a broken log)


def _check_repeats(t: np.ndarray, c: np.ndarray, first: np.ndarray, source: str, geographic: bool,
                   absolute: bool) -> None:
    """Warn when samples of one time (sorted ``t [S]``, ``c [S, 2]``; ``first``: the sample kept of each time)
    lie more than :data:`REPEAT_WARN` metres from the one kept, naming the time and distance; refuse
    (:class:`DatasetError`) beyond :data:`REPEAT_REFUSE`."""
    if first.all():
        return
    kept = c[np.flatnonzero(first)[np.cumsum(first) - 1]]  # the sample kept for each row's time
    d = c - kept
    if geographic:
        d = np.stack([d[:, 0] * 111320.0, d[:, 1] * 111320.0 * np.cos(np.radians(c[:, 0]))], axis=1)
    dist = np.linalg.norm(d, axis=1)
    worst = int(np.argmax(dist))
    if dist[worst] <= REPEAT_WARN:
        return
    when = (datetime.datetime.fromtimestamp(t[worst], datetime.timezone.utc).isoformat() if absolute
            else f"{t[worst]:g} s")
    n = int((dist > REPEAT_WARN).sum())
    said = "1 sample repeats" if n == 1 else f"{n} samples repeat"
    msg = (f"{shown(source)}: {said} a time with another position, up to {dist[worst]:.0f} m apart (at {when}): two "
           "receivers merged?")
    if dist[worst] > REPEAT_REFUSE:
        raise DatasetError(msg + " (hint: keep one receiver's fixes)")
    logger.warning("%s; the first sample of each time is used", msg)
