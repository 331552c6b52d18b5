"""The frames of a video placed by a track: :func:`place_video` joins a positions file (GPX, NMEA, CSV) to the
video's clock, interpolates each frame's position, drops (and counts) the frames outside the track, and keeps
one frame per second fraction (``fps``) or per ``every_metres`` travelled."""

from __future__ import annotations

import dataclasses
import datetime
from pathlib import Path

import numpy as np

from ..core.errors import ConfigError
from ..core.log import logger
from ..security.text import shown
from .sampling import every_metres as by_metres
from .sampling import every_seconds
from .tracks import read_track
from .tracks.clock import check_placed, video_times
from .tracks.interpolate import DEFAULT_MAX_GAP, at_times
from .tracks.metres import to_metres
from .video import VideoFile, VideoFrame


@dataclasses.dataclass
class Placed:
    """Frames of one video: ``frames`` (:class:`VideoFrame` s), ``names``, ``positions [K, 2]`` metres in
    ``frame`` (None without a track), the counts ``total`` / ``outside`` (dropped: no position) / ``kept``, and
    ``stream``: the number of the video stream read (0: the file's first); ``track_times``: ``seconds`` (since the
    video's start) or ``absolute``, the kind of its track's times (None without a track)."""

    frames: list[VideoFrame]
    names: list[str]
    positions: np.ndarray | None
    frame: str | None
    counts: dict[str, int]
    stream: int = 0
    track_times: str | None = None


@dataclasses.dataclass(frozen=True)
class JoinedTrack:
    """A track joined to a video's clock: its fixes' ``times [S]`` (seconds since the video's first frame) at
    ``xy [S, 2]`` metres in ``frame``; ``geographic``: read as latitude / longitude; ``absolute``: its times were
    absolute (ISO-8601, GPX, NMEA, Unix epoch), not seconds since the video's start."""

    times: np.ndarray
    xy: np.ndarray
    frame: str
    geographic: bool
    absolute: bool = True

    def at(self, times: np.ndarray, max_gap: float = DEFAULT_MAX_GAP) -> tuple[np.ndarray, np.ndarray]:
        """``(xy [N, 2], inside [N])`` at the frame ``times [N]`` (:func:`at_times`)."""
        return at_times(self.times, self.xy, times, max_gap)


def join_track(positions: str | Path, start: datetime.datetime | None, duration: float,
               zone: tuple[int, str] | None = None, side: str | None = None) -> JoinedTrack:
    """The track in ``positions`` on the clock of a video recorded from ``start``, ``duration`` s long, in metres
    (UTM ``zone`` when given); ``side``: which video of a two-video build, named in its refusals."""
    track = read_track(positions)
    xy, frame = to_metres(track, zone)
    return JoinedTrack(video_times(track, start, duration, side), xy, frame, track.geographic, track.absolute)


def track_positions(positions: str | Path, times: np.ndarray, start: datetime.datetime | None, duration: float,
                    zone: tuple[int, str] | None = None,
                    max_gap: float = DEFAULT_MAX_GAP) -> tuple[np.ndarray, np.ndarray, str]:
    """``(xy [N, 2], inside [N], frame)``: the positions at ``times [N]`` (seconds of a video recorded from
    ``start``, ``duration`` s long) on the track in ``positions``, in metres (UTM ``zone`` when given)."""
    joined = join_track(positions, start, duration, zone)
    return (*joined.at(times, max_gap), joined.frame)


def place_video(path: str | Path, positions: str | Path | None = None, fps: float | None = None,
                every_metres: float | None = None, video_start: datetime.datetime | None = None,
                zone: tuple[int, str] | None = None, max_gap: float = DEFAULT_MAX_GAP, stream: int | None = None,
                flag: str = "--stream", side: str | None = None) -> Placed:
    """The frames of the video ``path`` kept and placed (see the module docstring); ``video_start`` overrides the
    container's ``creation_time``; ``zone``: the UTM zone positions are computed in (default: the track's);
    ``stream``: which of its video streams (:func:`~seqnet.sources.video.choose_stream`, ``flag`` names it);
    ``side``: which video of a two-video build (named in the clock's refusals)."""
    if every_metres is not None and positions is None:
        raise ConfigError("--every-metres needs positions (--ref-positions / --query-positions FILE)")
    video = VideoFile(path, stream, flag)
    idx = np.arange(len(video))
    xy, frame, kind = None, None, None
    if positions is not None:
        joined = join_track(positions, video_start or video.start, video.duration, zone, side)
        xy, inside = joined.at(video.times, max_gap)
        frame, placed = joined.frame, int(inside.sum())
        kind = "absolute" if joined.absolute else "seconds"
        check_placed(placed, len(video.times), joined.times, video.duration, max_gap,
                     f"the track {shown(positions)} places {placed or 'none'} of the {len(video.times)} frames of "
                     f"the video {shown(path)}", video.times, inside)
        idx = idx[inside]
    if every_metres is not None:
        idx = idx[by_metres(xy[idx], every_metres)]
    elif fps is not None:
        idx = idx[every_seconds(video.times[idx], fps)]
    counts = {"total": len(video), "outside": 0 if xy is None else int(len(video) - inside.sum()), "kept": len(idx)}
    if counts["outside"]:
        logger.warning("%s: %d of %d frames lie outside the track %s (no position): dropped (the track covers %.1f .. "
                       "%.1f s of the video's 0 .. %.1f s)", path, counts["outside"], counts["total"], positions,
                       joined.times[0], joined.times[-1], video.duration)
    frames = [VideoFrame(video, int(i)) for i in idx]
    return Placed(frames, [f.name for f in frames], None if xy is None else xy[idx], frame, counts,
                  video.stream_number, kind)

