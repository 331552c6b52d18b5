"""The frames of a video placed by a track: :func:`place_video` joins a positions file (GPX, NMEA, CSV) to the
video's clock, interpolates each frame's position, drops (and counts) the frames outside the track, and keeps
one frame per second fraction (``fps``) or per ``every_metres`` travelled."""

from __future__ import annotations

import dataclasses
import datetime
from pathlib import Path

import numpy as np

from ..core.errors import ConfigError, DatasetError
from ..core.log import logger
from ..security.text import shown
from .sampling import every_metres as by_metres
from .sampling import every_seconds
from .tracks import read_track
from .tracks.clock import in_milliseconds, video_times, why_outside
from .tracks.interpolate import DEFAULT_MAX_GAP, at_times
from .tracks.metres import to_metres
from .video import VideoFile, VideoFrame


@dataclasses.dataclass
class Placed:
    """Frames of one video: ``frames`` (:class:`VideoFrame` s), ``names``, ``positions [K, 2]`` metres in
    ``frame`` (None without a track), and the counts ``total`` / ``outside`` (dropped: no position) / ``kept``."""

    frames: list[VideoFrame]
    names: list[str]
    positions: np.ndarray | None
    frame: str | None
    counts: dict[str, int]


def track_positions(positions: str | Path, times: np.ndarray, start: datetime.datetime | None, duration: float,
                    zone: tuple[int, str] | None = None,
                    max_gap: float = DEFAULT_MAX_GAP) -> tuple[np.ndarray, np.ndarray, str]:
    """``(xy [N, 2], inside [N], frame)``: the positions at ``times [N]`` (seconds of a video recorded from
    ``start``, ``duration`` s long) on the track in ``positions``, in metres (UTM ``zone`` when given)."""
    track = read_track(positions)
    rel = video_times(track, start, duration)
    xy_track, frame = to_metres(track, zone)
    xy, inside = at_times(rel, xy_track, times, max_gap)
    return xy, inside, frame


def place_video(path: str | Path, positions: str | Path | None = None, fps: float | None = None,
                every_metres: float | None = None, video_start: datetime.datetime | None = None,
                zone: tuple[int, str] | None = None, max_gap: float = DEFAULT_MAX_GAP) -> Placed:
    """The frames of the video ``path`` kept and placed (see the module docstring); ``video_start`` overrides the
    container's ``creation_time``; ``zone``: the UTM zone positions are computed in (default: the track's)."""
    if every_metres is not None and positions is None:
        raise ConfigError("--every-metres needs positions (--ref-positions / --query-positions FILE)")
    video = VideoFile(path)
    idx = np.arange(len(video))
    xy, frame = None, None
    if positions is not None:
        xy, inside, frame = track_positions(positions, video.times, video_start or video.start, video.duration,
                                            zone, max_gap)
        _check_placed(int(inside.sum()), video, positions, video_start or video.start, max_gap)
        idx = idx[inside]
    if every_metres is not None:
        idx = idx[by_metres(xy[idx], every_metres)]
    elif fps is not None:
        idx = idx[every_seconds(video.times[idx], fps)]
    counts = {"total": len(video), "outside": 0 if xy is None else int(len(video) - inside.sum()), "kept": len(idx)}
    if counts["outside"]:
        logger.warning("%s: %d of %d frames lie outside the track %s (no position): dropped", path,
                       counts["outside"], counts["total"], positions)
    frames = [VideoFrame(video, int(i)) for i in idx]
    return Placed(frames, [f.name for f in frames], None if xy is None else xy[idx], frame, counts)


def _check_placed(placed: int, video: VideoFile, positions: str | Path, start: datetime.datetime | None,
                  max_gap: float) -> None:
    """Refuse a track that places no frame of ``video``, or under half of them with times that look like
    milliseconds (a dataset of a frame or two is no dataset), naming why (:func:`why_outside`)."""
    n = len(video.times)
    if 2 * placed >= n:
        return
    rel = video_times(read_track(positions), start, video.duration)
    where = f"the track {shown(positions)} places {placed or 'none'} of the {n} frames of the video {shown(video.path)}"
    if not placed or in_milliseconds(rel, video.duration):
        raise DatasetError(f"{where}: {why_outside(rel, video.duration, max_gap)}")
