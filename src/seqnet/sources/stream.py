"""A video read as a stream: frames decoded one at a time, in order, as they come (:class:`FrameStream`).

The source is a live stream (a URL, ``/dev/videoN``: :func:`seqnet.security.videos.open_stream`, with a timeout,
so a stream that stalls ends with a message, not a hang) or a video file read from start to end. Each frame is a
:class:`StreamFrame` named by its time (seconds from the first frame, by the stream's timestamps). ``fps`` keeps
the first frame of each ``1 / fps`` seconds. ``realtime`` paces a file by its own clock (a frame is handed over
no earlier than its time after the first) and, file or live, drops a frame that comes when the consumer is more
than ``lag`` seconds behind its time (counted in :attr:`FrameStream.dropped`).
"""

from __future__ import annotations

import datetime
import math
import time
from collections.abc import Callable, Iterator
from typing import Any

from ..core.errors import DatasetError
from ..security.text import shown
from ..security.videos import DEFAULT_TIMEOUT, av_errors, check_size, is_stream_name, open_stream, why
from .video import choose_stream, creation_time, frame_image, frame_name


class StreamFrame:
    """One decoded frame of a :class:`FrameStream`: an :class:`~seqnet.describe.images.ImageItem` named by its
    time; it holds the decoded frame until it is dropped."""

    __slots__ = ("frame", "time", "source")

    def __init__(self, frame: Any, t: float, source: str) -> None:
        self.frame, self.time, self.source = frame, t, source

    @property
    def name(self) -> str:
        return frame_name(self.time)

    def open(self) -> Any:
        """The frame as an upright RGB PIL image (:func:`~seqnet.sources.video.frame_image`)."""
        return frame_image(self.frame)

    def key(self) -> str:
        return f"{self.source}@{self.name}"

    def __str__(self) -> str:
        return f"{self.source}@{self.name}"


class FrameStream:
    """The frames of ``name`` (a URL, ``/dev/videoN`` or a video file) in order; iterate once. :attr:`start`: when
    its first frame was recorded (a file's ``creation_time``; a live stream's arrival of its first frame), known
    after the first frame; :attr:`decoded`, :attr:`dropped` and :attr:`decode_ms` (per frame handed over).
    ``stream``: which video stream of several (:func:`~seqnet.sources.video.choose_stream`; ``flag`` names it)."""

    def __init__(self, name: str, fps: float | None = None, realtime: bool = False, timeout: float = DEFAULT_TIMEOUT,
                 lag: float | None = None, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep, stream: int | None = None,
                 flag: str = "--stream") -> None:
        self.name, self.fps, self.realtime, self.timeout = str(name), fps, realtime, timeout
        self.live = is_stream_name(self.name)
        self.container, self._file = open_stream(self.name, timeout)
        try:
            self.stream, self.stream_number = choose_stream(self.container, self.name, stream, flag)
        except BaseException:
            self.close()
            raise
        rate = float(self.stream.average_rate or 0) or 30.0
        self.lag = lag if lag is not None else 1.5 / rate  # behind by more than a frame and a half: dropped
        self.start = None if self.live else creation_time(self.container, self.stream)
        self.clock, self.sleep = clock, sleep
        self.decoded = self.dropped = 0
        self.decode_ms: list[float] = []  # per frame handed over: decoding it and the frames skipped before it
        self._pending_ms = 0.0

    def _decoded(self) -> Iterator[Any]:
        """The stream's frames as PyAV decodes them; its failures (a stall past the timeout) one DatasetError."""
        frames = self.container.decode(self.stream)
        while True:
            t0 = time.perf_counter()
            try:
                frame = next(frames)
            except StopIteration:
                return
            except av_errors() as e:
                stall = f"; no frame within {self.timeout:g} s?" if self.live else ""
                raise DatasetError(f"the stream {shown(self.name)[:120]} failed after {self.decoded} frames "
                                   f"({why(e)}{stall})") from e
            check_size(frame.width, frame.height, self.name)
            self._pending_ms += (time.perf_counter() - t0) * 1e3  # decoding (and waiting for) the frame
            yield frame

    def __iter__(self) -> Iterator[StreamFrame]:
        t_first, wall0, last_bin = None, None, -1
        try:
            for frame in self._decoded():
                now = self.clock()
                t = frame.time
                if t_first is None:
                    t_first = t if t is not None else 0.0
                    wall0 = now
                    if self.start is None and self.live:
                        self.start = datetime.datetime.now(datetime.timezone.utc)
                t = (now - wall0) if t is None else t - t_first
                if self.fps is not None:
                    b = math.floor(t * self.fps + 1e-6)
                    if b <= last_bin:
                        continue
                    last_bin = b
                self.decoded += 1
                if self.realtime:
                    behind = now - wall0 - t
                    if behind > self.lag:
                        self.dropped += 1
                        continue
                    if behind < 0 and not self.live:
                        self.sleep(-behind)
                self.decode_ms.append(self._pending_ms)
                self._pending_ms = 0.0
                yield StreamFrame(frame, t, self.name)
        finally:
            self.close()

    def close(self) -> None:
        """Close the stream (and its file)."""
        self.container.close()
        if self._file is not None:
            self._file.close()
