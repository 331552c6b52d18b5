"""Joining a track's clock to a video's: every track time as seconds since the video's first frame.

A track in seconds since the video's start (a CSV of numbers) is taken as it is. A track of absolute times (GPX,
NMEA, ISO-8601 or Unix epoch times in a CSV) is placed by the video's own clock, the time its first frame was
recorded: the container's ``creation_time``, or ``--video-start`` (which wins: a phone may store the end of the
recording, or local time as UTC). A track that does not overlap the video is refused, never shifted: another
day's track by its date, the same day's by both time spans.
"""

from __future__ import annotations

import datetime

import numpy as np

from ...core.errors import ConfigError, DatasetError
from ...security.text import shown
from ..times import parse_iso
from .base import Track

DAY = 86400.0
MAX_ZONE = 14.0  # hours: the largest offset of a time zone from UTC
MS_RATIO = 200.0  # a track spanning this many times the video's length: its times are probably milliseconds
UNIT_RATIOS = ((2e5, "milliseconds"), (2e8, "microseconds"), (float("inf"), "nanoseconds"))  # span / duration below


def parse_start(text: str) -> datetime.datetime:
    """``--video-start``: an ISO-8601 time (one without a zone is UTC) as an aware datetime."""
    try:
        return parse_iso(text)
    except ValueError as e:
        raise ConfigError(f"--video-start {shown(text)[:60]} is not an ISO-8601 time (e.g. "
                          "2024-05-01T10:00:00Z)") from e


def _utc(seconds: float) -> str:
    return datetime.datetime.fromtimestamp(seconds, datetime.timezone.utc).strftime("%Y-%m-%d %H:%M:%S")


def _video(side: str | None) -> tuple[str, str]:
    """``("the query video", "--video-start query=")`` of a two-video build's ``side``; ``("the video",
    "--video-start ")`` for one video."""
    return ("the video", "--video-start ") if side is None else (f"the {side} video", f"--video-start {side}=")


def video_times(track: Track, start: datetime.datetime | None, duration: float,
                side: str | None = None) -> np.ndarray:
    """``[S]`` the track's times in seconds since the video's first frame (``start``: when it was recorded;
    ``duration``: seconds of video). :class:`ConfigError` when absolute times meet a video without a start;
    :class:`DatasetError` when the track does not overlap the video (another day: by its date). ``side``: which
    video of a two-video build (``"reference"``, ``"query"``), named in the messages and their hints."""
    noun, flag = _video(side)
    if not track.absolute:
        return track.times
    if start is None:
        kind = f" (Unix epoch {track.epoch}: {_utc(track.times[0])} UTC on)" if track.epoch else ""
        raise ConfigError(f"{shown(track.source)} has absolute times{kind}, but {noun} records no creation_time; "
                          f"give its start with {flag}ISO-8601 (e.g. {flag}2024-05-01T10:00:00Z)")
    t0 = start.timestamp()
    times = track.times
    if not track.dated:  # NMEA GGA only: times of day, taken on the video's (UTC) day
        times = times + (t0 - t0 % DAY)
    rel = times - t0
    if rel[-1] < 0 or rel[0] > duration:
        _refuse_hours_off(track, rel, start, duration, side)
        day_t, day_v = _utc(times[0])[:10], _utc(t0)[:10]
        if day_t != day_v and _utc(times[-1])[:10] != day_v:
            raise DatasetError(f"{shown(track.source)} is a track of {day_t} (UTC), {noun} was recorded on {day_v}: "
                               f"a track of another day is refused, not shifted (hint: {flag}ISO if {noun}'s clock "
                               "is wrong)")
        raise DatasetError(f"{shown(track.source)} does not overlap {noun}: the track spans {_utc(times[0])} .. "
                           f"{_utc(times[-1])} UTC, {noun} {_utc(t0)} .. {_utc(t0 + duration)} UTC (hint: "
                           f"{flag}ISO if {noun}'s clock is wrong)")
    return rel


def hours_off(rel: np.ndarray, duration: float) -> float | None:
    """The whole number of half hours (in hours, within :data:`MAX_ZONE` h) by which a track of times ``rel [S]``
    (seconds since the video's first frame) that misses a ``duration`` s video would overlap it when shifted
    earlier: a clock in local time read as UTC (or the other way round); None when no such shift overlaps."""
    k = round(float(rel[0]) / 1800.0) * 1800.0
    if k == 0 or abs(k) > MAX_ZONE * 3600.0:
        return None
    return k / 3600.0 if rel[-1] - k >= 0 and rel[0] - k <= duration else None


def _refuse_hours_off(track: Track, rel: np.ndarray, start: datetime.datetime, duration: float,
                      side: str | None = None) -> None:
    """Refuse (:class:`DatasetError`) a track a whole number of hours off the video, naming the likely fix: the
    zone of a track written in local time without one, else the video's clock (``--video-start``, of ``side``)."""
    noun, flag = _video(side)
    h = hours_off(rel, duration)
    if h is None:
        return
    way = "after" if h > 0 else "before"
    said = (f"{shown(track.source)} does not overlap {noun}: the track spans {_utc(track.times[0])} .. "
            f"{_utc(track.times[-1])} UTC, {abs(h):g} h {way} {noun}'s {_utc(start.timestamp())} .. "
            f"{_utc(start.timestamp() + duration)} UTC")
    if not track.zoned:
        zone = f"{'+' if h > 0 else '-'}{int(abs(h)):02d}:{round(abs(h) % 1 * 60):02d}"
        raise DatasetError(f"{said}: local time? its times name no zone and are read as UTC (hint: write them with "
                           f"their zone, e.g. {_utc(track.times[0]).replace(' ', 'T')}{zone})")
    fixed = datetime.datetime.fromtimestamp(start.timestamp() + h * 3600.0, datetime.timezone.utc)
    raise DatasetError(f"{said}: {noun}'s clock in another time zone, or the track's times written as UTC while "
                       f"local? (hint: {flag}{fixed.strftime('%Y-%m-%dT%H:%M:%S')}Z, or correct the track's times)")


def in_milliseconds(track_times: np.ndarray, duration: float) -> bool:
    """Whether a track of sorted times ``[S]`` spans far more than the ``duration`` s video it goes with
    (:data:`MS_RATIO` times): times written in milliseconds (or a smaller unit: :func:`time_unit`), read as
    seconds."""
    return time_unit(track_times, duration) is not None


def time_unit(track_times: np.ndarray, duration: float) -> str | None:
    """The unit the times ``[S]`` (sorted) of a track far longer than its ``duration`` s video were probably
    written in, by the ratio of the spans (about 1e3: ``milliseconds``, 1e6: ``microseconds``, 1e9:
    ``nanoseconds``; :data:`UNIT_RATIOS`); None when the spans are alike (under :data:`MS_RATIO` times)."""
    t = np.asarray(track_times, np.float64)
    if not (len(t) > 1 and duration > 0 and t[-1] - t[0] > MS_RATIO * duration):
        return None
    ratio = (t[-1] - t[0]) / duration
    return next(name for bound, name in UNIT_RATIOS if ratio < bound)


def why_outside(track_times: np.ndarray, duration: float, max_gap: float, frame_times: np.ndarray | None = None,
                inside: np.ndarray | None = None) -> str:
    """Why frames of a ``duration`` s video lie off a track of sorted times ``[S]`` (seconds since the video's
    first frame): times in milliseconds, no overlap, a track that covers only part of the video (with the frames'
    ``frame_times [N]`` and ``inside [N]``: how many lie before its start, after its end and in its gaps,
    :func:`coverage`), or frames inside a gap longer than ``max_gap``."""
    t = np.asarray(track_times, np.float64)
    span = float(t[-1] - t[0]) if len(t) else 0.0
    unit = time_unit(t, duration)
    if unit is not None:
        return (f"the track spans {span:.0f} s against a video of {duration:.1f} s: times in {unit}? (numeric "
                "times are read as seconds since the video's start, unless they are Unix epoch times)")
    if t[-1] < 0 or t[0] > duration:
        return (f"the track's times ({t[0]:.3g} .. {t[-1]:.3g} s) do not overlap the video's 0 .. {duration:.1f} s "
                "(numeric times are read as seconds since the video's start; absolute ones need the video's "
                "creation_time or --video-start)")
    partial = bool(t[0] > 0 or t[-1] < duration)
    said = coverage(t, duration, max_gap, frame_times, inside) if partial and frame_times is not None else None
    gaps = np.diff(t)
    within = (t[:-1] < duration) & (t[1:] > 0) & (gaps > max_gap)
    if said is None and within.any():
        return (f"the video's frames fall inside a gap of the track of {float(gaps[within].max()):.3g} s, longer "
                f"than the {max_gap:g} s a frame is interpolated across (--max-gap) (the track has {len(t)} fixes "
                f"over {span:.3g} s: times in milliseconds, or a sparse track?)")
    return said or coverage(t, duration, max_gap) or ""


def coverage(track_times: np.ndarray, duration: float, max_gap: float, frame_times: np.ndarray | None = None,
             inside: np.ndarray | None = None) -> str | None:
    """``the track covers 0 .. 14.8 s of the video's 0 .. 30.0 s: the 151 frames after its end have no
    position`` for a track of times ``[S]`` (seconds since the video's first frame) overlapping a ``duration`` s
    video in part; the counts of frames before its start, after its end and in its gaps (longer than
    ``max_gap``) need the frames' ``frame_times [N]`` and ``inside [N]``. None when it leaves no frame out."""
    t = np.asarray(track_times, np.float64)
    shown_span = f"{max(float(t[0]), 0.0):.3g} .. {min(float(t[-1]), duration):.3g} s"
    head = f"the track covers {shown_span} of the video's 0 .. {duration:.1f} s"
    if frame_times is None or inside is None:
        return f"{head}: the frames outside it have no position"
    ft, off = np.asarray(frame_times, np.float64), ~np.asarray(inside, bool)
    before, after = int((off & (ft < t[0])).sum()), int((off & (ft > t[-1])).sum())
    parts = [(k, what) for k, what in ((before, "before its start"), (after, "after its end"),
                                       (int(off.sum()) - before - after,
                                        f"in its gaps of more than {max_gap:g} s (--max-gap)")) if k]
    if not parts:
        return None
    if len(parts) == 1:
        k, what = parts[0]
        return f"{head}: {'the frame' if k == 1 else f'the {k} frames'} {what} {'has' if k == 1 else 'have'} " \
            "no position"
    listed = ", ".join(f"{k} {what}" for k, what in parts)
    return f"{head}: {int(off.sum())} frames have no position ({listed})"


def check_placed(placed: int, n: int, track_times: np.ndarray, duration: float, max_gap: float,
                 said: str, frame_times: np.ndarray | None = None, inside: np.ndarray | None = None) -> str | None:
    """Refuse (:class:`DatasetError`, ``said: why``) a track that places ``placed`` of a video's ``n`` frames when
    that is none, or under half with times that look like milliseconds (a dataset of a frame or two is no dataset);
    under half otherwise: that line, to warn with (:func:`why_outside`, with the frames' ``frame_times [N]`` and
    ``inside [N]`` when given: how many lie before, after and within the track); else None. ``track_times [S]``:
    the track's times in seconds since the video's first frame, ``duration``: the video's seconds."""
    if 2 * placed >= n:
        return None
    line = f"{said}: {why_outside(track_times, duration, max_gap, frame_times, inside)}"
    if not placed or in_milliseconds(track_times, duration):
        raise DatasetError(line)
    return line
