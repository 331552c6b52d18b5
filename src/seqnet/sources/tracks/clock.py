"""Joining a track's clock to a video's: every track time as seconds since the video's first frame.

A track in seconds since the video's start (a CSV of numbers) is taken as it is. A track of absolute times (GPX,
NMEA, ISO-8601 CSV) is placed by the video's own clock, the time its first frame was recorded: the container's
``creation_time``, or ``--video-start`` (which wins: a phone may store the end of the recording, or local time
as UTC). A track that does not overlap the video is refused, never shifted: another day's track by its date,
the same day's by both time spans.
"""

from __future__ import annotations

import datetime

import numpy as np

from ...core.errors import ConfigError, DatasetError
from ...security.text import shown
from ..times import parse_iso
from .base import Track

DAY = 86400.0


def parse_start(text: str) -> datetime.datetime:
    """``--video-start``: an ISO-8601 time (one without a zone is UTC) as an aware datetime."""
    try:
        return parse_iso(text)
    except ValueError as e:
        raise ConfigError(f"--video-start {shown(text)[:60]} is not an ISO-8601 time (e.g. "
                          "2024-05-01T10:00:00Z)") from e


def _utc(seconds: float) -> str:
    return datetime.datetime.fromtimestamp(seconds, datetime.timezone.utc).strftime("%Y-%m-%d %H:%M:%S")


def video_times(track: Track, start: datetime.datetime | None, duration: float) -> np.ndarray:
    """``[S]`` the track's times in seconds since the video's first frame (``start``: when it was recorded;
    ``duration``: seconds of video). :class:`ConfigError` when absolute times meet a video without a start;
    :class:`DatasetError` when the track does not overlap the video (another day: by its date)."""
    if not track.absolute:
        return track.times
    if start is None:
        raise ConfigError(f"{shown(track.source)} has absolute times, but the video records no creation_time; give "
                          "its start with --video-start ISO-8601 (e.g. 2024-05-01T10:00:00Z)")
    t0 = start.timestamp()
    times = track.times
    if not track.dated:  # NMEA GGA only: times of day, taken on the video's (UTC) day
        times = times + (t0 - t0 % DAY)
    rel = times - t0
    if rel[-1] < 0 or rel[0] > duration:
        day_t, day_v = _utc(times[0])[:10], _utc(t0)[:10]
        if day_t != day_v and _utc(times[-1])[:10] != day_v:
            raise DatasetError(f"{shown(track.source)} is a track of {day_t} (UTC), the video was recorded on {day_v}: "
                               "a track of another day is refused, not shifted (hint: --video-start if the video's "
                               "clock is wrong)")
        raise DatasetError(f"{shown(track.source)} does not overlap the video: the track spans {_utc(times[0])} .. "
                           f"{_utc(times[-1])} UTC, the video {_utc(t0)} .. {_utc(t0 + duration)} UTC (hint: "
                           "--video-start if the video's clock is wrong)")
    return rel
