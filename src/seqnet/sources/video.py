"""A video file as a frame source: :class:`VideoFile` lists its frames' times, :class:`VideoFrame` is one frame.

Opening reads the container's packets once, without decoding (their presentation timestamps: the frames'
times, in seconds from the first frame), through :func:`seqnet.security.videos.open_video_file`. A frame is
decoded when it is opened: frames opened in order cost one decoding pass (one frame in memory at a time);
any other frame is reached by seeking to the keyframe before it. Each frame is named by its video time
(``12.345678``, seconds), so positions join it by time; :func:`video_images` lists the frames of a video
(every frame, or ``fps`` per second of video). A frame comes upright (:func:`frame_image`): the stream's display
rotation (what phones write instead of rotating the pixels) is applied, as players do. A file of several video
streams (a dual-camera dashcam's front and rear) is read from the one :func:`choose_stream` picks: the number
given (``--stream N``: 0 is the first video stream), else the first that is not a cover picture, said in a warning
listing them all.
"""

from __future__ import annotations

import datetime
import weakref
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ConfigError, DatasetError, ImageError
from ..core.log import logger, warn_once
from ..security.text import shown
from ..security.videos import av_errors, check_size, is_cover, open_video_file, why
from .sampling import every_seconds
from .times import parse_iso

VIDEO_SUFFIXES = (".mp4", ".m4v", ".mov", ".mkv", ".webm", ".avi", ".ts", ".mts", ".m2ts", ".mpg", ".mpeg", ".flv",
                  ".ogv", ".3gp")
MAX_FRAMES = 50_000_000  # packets of one video stream
SEEK_AHEAD = 120  # frames: a frame further ahead than this in a pass is reached by seeking


def is_video(path: str | Path) -> bool:
    """Whether ``path`` names a video file (by its suffix, :data:`VIDEO_SUFFIXES`)."""
    return Path(path).suffix.lower() in VIDEO_SUFFIXES


def frame_name(t: float) -> str:
    """The name of the frame at ``t`` seconds of video: ``12.345678``."""
    return f"{t:.6f}"


def creation_time(*holders: Any) -> datetime.datetime | None:
    """The ``creation_time`` of the container's (or stream's) metadata as an aware UTC datetime; None when absent,
    unreadable, or a placeholder (before 1971: an unset MP4 date)."""
    for h in holders:
        text = str((getattr(h, "metadata", None) or {}).get("creation_time", "")).strip()
        try:
            t = parse_iso(text) if text else None
        except ValueError:
            t = None
        if t is not None:
            return t if t.year > 1970 else None
    return None


def frame_image(frame: Any) -> Any:
    """A decoded PyAV ``VideoFrame`` as an RGB PIL image the way players show it: turned by its display rotation
    (``frame.rotation``, degrees counter-clockwise, from the stream's display matrix; rounded to a quarter turn)."""
    from PIL import Image

    im = frame.to_image()
    if not hasattr(frame, "rotation"):
        warn_once(("no frame rotation",), "this PyAV does not give a frame's display rotation: a phone video stored "
                  "sideways is read sideways (hint: pip install -U av)")
    quarter = round(float(getattr(frame, "rotation", 0) or 0) / 90) % 4
    t = Image.Transpose
    return im if quarter == 0 else im.transpose((t.ROTATE_90, t.ROTATE_180, t.ROTATE_270)[quarter - 1])


def _said(i: int, stream: Any) -> str:
    cc = stream.codec_context
    return f"{i}: {cc.width}x{cc.height}" + (" cover picture" if is_cover(stream) else "")


def choose_stream(container: Any, where: Any, number: int | None = None, flag: str = "--stream") -> tuple[Any, int]:
    """``(stream, n)``: video stream ``number`` of an open container (0: its first video stream), else the first
    that is not a cover picture; more than one such video stream is warned (their sizes, the one used, ``flag``), a
    ``number`` it lacks or a cover picture is a :class:`ConfigError`. Its frame size was checked on opening
    (:func:`seqnet.security.videos.check_streams`)."""
    streams = list(container.streams.video)
    listed = ", ".join(_said(i, s) for i, s in enumerate(streams))
    if number is not None:
        if not 0 <= number < len(streams) or is_cover(streams[number]):
            what = "is a cover picture, not a video" if 0 <= number < len(streams) else "does not exist"
            raise ConfigError(f"{flag} {number}: video stream {number} of {shown(where)} {what}; it holds "
                              f"{len(streams)} video stream{'s' if len(streams) != 1 else ''} ({listed})")
        chosen = number
    else:
        videos = [i for i, s in enumerate(streams) if not is_cover(s)] or [0]
        chosen = videos[0]
        if len(videos) > 1:
            logger.warning("%s has %d video streams (%s); using %d (hint: %s N picks another, 0 the first)",
                           where, len(streams), listed, chosen, flag)
    return streams[chosen], chosen  # its frame size was checked on opening (security.videos.check_streams)


def _close(container: Any, file: Any) -> None:
    container.close()
    file.close()


class VideoFile:
    """The frames of one video stream of a file (:func:`choose_stream`; :attr:`stream_number`): :attr:`pts`
    ``[N]`` (in order), :attr:`times` ``[N]`` (seconds from the first frame), :attr:`start` (when it was
    recorded, or None) and :attr:`duration` (s).
    The file stays open for :meth:`read` until :meth:`close` (or the object goes away)."""

    def __init__(self, path: str | Path, stream: int | None = None, flag: str = "--stream") -> None:
        self.path = Path(path)
        self.container, file = open_video_file(self.path)
        self._finalizer = weakref.finalize(self, _close, self.container, file)
        self.stream, self.stream_number = choose_stream(self.container, self.path, stream, flag)
        self.pts = self._index()
        self.time_base = float(self.stream.time_base)
        self.times = (self.pts - self.pts[0]) * self.time_base
        rate = float(self.stream.average_rate or 0) or (1 / float(np.median(np.diff(self.times)))
                                                         if len(self.times) > 1 else 1.0)
        self.duration = float(self.times[-1] + 1 / rate)
        self.start = creation_time(self.container, self.stream)
        self._pass: Iterator[Any] | None = None
        self._next = 0  # index of the frame the pass reaches next

    def _index(self) -> np.ndarray:
        """``[N]`` the presentation timestamps of the stream's packets, sorted (one packet per frame)."""
        pts: list[int] = []
        try:
            for packet in self.container.demux(self.stream):
                if packet.size == 0:  # the demuxer's end marker
                    continue
                p = packet.pts if packet.pts is not None else packet.dts
                if p is None:
                    raise DatasetError(f"video {shown(self.path)}: frame {len(pts)} has no timestamp; frames are "
                                       "placed by time (hint: remux it, e.g. ffmpeg -i IN -c copy OUT.mp4)")
                pts.append(int(p))
                if len(pts) > MAX_FRAMES:
                    raise DatasetError(f"video {shown(self.path)} has more than {MAX_FRAMES:,} frames")
        except av_errors() as e:
            raise DatasetError(f"cannot read the video {shown(self.path)} ({why(e)}; is it damaged or "
                               "truncated?)") from e
        if not pts:
            raise DatasetError(f"video {shown(self.path)} has no frames")
        out = np.sort(np.asarray(pts, np.int64))
        if (np.diff(out) == 0).any():
            raise DatasetError(f"video {shown(self.path)}: two frames share a timestamp; frames are named and placed "
                               "by time (hint: re-encode it)")
        return out

    def __len__(self) -> int:
        return len(self.pts)

    def _decoded(self, pts: int) -> Iterator[Any]:
        self.container.seek(int(pts), stream=self.stream, backward=True, any_frame=False)
        yield from self.container.decode(self.stream)

    def read(self, index: int) -> Any:
        """Frame ``index`` decoded (a PyAV ``VideoFrame``), its size checked; a damaged frame is an
        :class:`ImageError` naming it."""
        want = int(self.pts[index])
        try:
            if self._pass is None or not self._next <= index <= self._next + SEEK_AHEAD:
                self._pass = self._decoded(want)
            for frame in self._pass:
                if frame.pts is None or frame.pts < want:
                    continue
                if frame.pts > want:
                    break
                self._next = index + 1
                check_size(frame.width, frame.height, self.path)
                return frame
        except av_errors() as e:
            self._pass = None
            raise ImageError(f"cannot decode frame {frame_name(self.times[index])} of the video {shown(self.path)} "
                             f"({why(e)}; hint: --skip-corrupted leaves such frames out)") from e
        self._pass = None
        raise ImageError(f"video {shown(self.path)}: frame {frame_name(self.times[index])} (listed in the container) "
                         "does not decode; is the video damaged or truncated? (hint: --skip-corrupted leaves such "
                         "frames out)")

    def close(self) -> None:
        """Close the container and its file (reads after it fail)."""
        self._finalizer()


class VideoFrame:
    """One frame of a :class:`VideoFile`: an :class:`~seqnet.describe.images.ImageItem` named by its time."""

    __slots__ = ("video", "index")

    def __init__(self, video: VideoFile, index: int) -> None:
        self.video, self.index = video, index

    @property
    def time(self) -> float:
        """Seconds from the video's first frame."""
        return float(self.video.times[self.index])

    @property
    def name(self) -> str:
        return frame_name(self.time)

    def open(self) -> Any:
        """The frame as an upright RGB PIL image (:func:`frame_image`; decoded from there by
        :func:`~seqnet.security.pictures.decode`)."""
        return frame_image(self.video.read(self.index))

    def key(self) -> str:
        """Identity for provenance hashes: the resolved video path and the frame's timestamp."""
        return f"{self.video.path.resolve()}@{int(self.video.pts[self.index])}"

    def __str__(self) -> str:
        return f"{self.video.path}@{self.name}"

    def __repr__(self) -> str:
        return f"VideoFrame({self})"

    def __deepcopy__(self, memo: dict) -> VideoFrame:
        return self  # a reference into an open video: copies share it


def video_images(path: str | Path, fps: float | None = None,
                 stream: int | None = None) -> tuple[list[VideoFrame], list[str]]:
    """``(frames, names)`` of the video ``path`` (its video ``stream``: :func:`choose_stream`): every frame, or the
    first of each ``1 / fps`` seconds."""
    video = VideoFile(path, stream)
    keep = range(len(video)) if fps is None else every_seconds(video.times, fps)
    frames = [VideoFrame(video, int(i)) for i in keep]
    names = [f.name for f in frames]
    if len(set(names)) != len(names):
        raise ImageError(f"video {shown(path)} has two frames within a microsecond; frames are named by time "
                         "(hint: --fps)")
    return frames, names
