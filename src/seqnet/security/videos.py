"""Opening a video file or a live stream with PyAV (FFmpeg), as an untrusted input.

* A file is opened without blocking (:func:`~seqnet.security.inputs.open_input`: no FIFO, socket or device)
  and handed to FFmpeg as that open file object, never as a path: FFmpeg opens no other file or URL for it.
* Its container is recognised from its first bytes (:data:`CONTAINERS`: MP4/MOV, Matroska/WebM, AVI, MPEG-TS,
  MPEG-PS, FLV, Ogg) and only that demuxer reads it; FFmpeg does not probe the bytes with every demuxer it has
  (a playlist or a concat list would make it open what they name).
* A frame size above ``max_pixels`` (:data:`~seqnet.security.pictures.MAX_PIXELS`) is refused from the header of
  every video stream that may be decoded (all but cover pictures), before a frame is decoded, and again for each
  frame decoded (a stream may change size).
* A live stream (a URL the user names, or a V4L2 device ``/dev/videoN``) is opened with a timeout: a stream that
  stalls is a :class:`~seqnet.core.errors.DatasetError` after ``timeout`` seconds, never a hang.
* Whatever PyAV raises on damaged bytes is one :class:`~seqnet.core.errors.DatasetError` naming the video.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

from ..core.errors import ConfigError, DatasetError
from .inputs import open_input, special_file
from .pictures import MAX_PIXELS
from .text import shown

CONTAINERS = {"mov": "MP4/MOV", "matroska": "Matroska/WebM", "avi": "AVI", "mpegts": "MPEG-TS", "mpeg": "MPEG-PS",
              "flv": "FLV", "ogg": "Ogg"}  # FFmpeg demuxer name: what it reads
MP4_BOXES = (b"ftyp", b"moov", b"mdat", b"free", b"wide", b"skip", b"pnot")
STREAM_SCHEMES = ("rtsp", "rtsps", "rtmp", "rtmps", "http", "https", "udp", "tcp", "srt")
URL = re.compile(r"([a-z][a-z0-9+.-]*)://", re.IGNORECASE)
DEVICE = re.compile(r"/dev/video[0-9]{1,3}")
DEFAULT_TIMEOUT = 10.0  # seconds a live stream may stall before it is given up
MAX_VIDEO_BYTES = 1 << 40  # a larger "video" is refused before FFmpeg reads it
ATTACHED_PIC = 0x400  # FFmpeg's AV_DISPOSITION_ATTACHED_PIC: a cover picture stored as a one-frame video stream


def container_of(head: bytes) -> str | None:
    """The FFmpeg demuxer of the container whose file starts with ``head`` (:data:`CONTAINERS`), else None."""
    if head[4:8] in MP4_BOXES:
        return "mov"
    if head.startswith(b"\x1a\x45\xdf\xa3"):
        return "matroska"
    if head.startswith(b"RIFF") and head[8:12] == b"AVI ":
        return "avi"
    if len(head) > 376 and head[0] == head[188] == head[376] == 0x47:
        return "mpegts"
    if head.startswith(b"\x00\x00\x01\xba"):
        return "mpeg"
    if head.startswith(b"FLV"):
        return "flv"
    if head.startswith(b"OggS"):
        return "ogg"
    return None


def av_errors() -> tuple[type[BaseException], ...]:
    """What PyAV and FFmpeg raise on a damaged or unreadable video."""
    import av

    return (av.FFmpegError, OSError, ValueError, EOFError, IndexError, KeyError, TypeError, OverflowError,
            MemoryError, UnicodeDecodeError)


def why(e: BaseException) -> str:
    """``Type: message`` of an exception, on one line, shown escaped and cut to 200 characters."""
    return f"{type(e).__name__}: {shown(' '.join(str(e).split()))[:200]}"


def open_video_file(path: str | os.PathLike[str]) -> tuple[Any, Any]:
    """``(container, file)``: the video file ``path`` opened by PyAV through its one recognised demuxer (close
    both: the container first). Refused with one :class:`DatasetError`: a missing or special file, an empty or
    oversized one, a container seqnet does not read, bytes FFmpeg cannot parse, no video stream."""
    import av

    kind = special_file(path)
    if kind:
        raise DatasetError(f"video {shown(path)} is a {kind}, not a regular file (hint: a live stream is named by its "
                           "URL or /dev/videoN)")
    f = open_input(path, "video")
    try:
        size = os.fstat(f.fileno()).st_size
        if not 0 < size <= MAX_VIDEO_BYTES:
            raise DatasetError(f"video {shown(path)} has {size} bytes; a video has 1 to {MAX_VIDEO_BYTES} bytes")
        fmt = container_of(f.read(512))
        f.seek(0)
        if fmt is None:
            raise DatasetError(f"{shown(path)} is not a video of a container seqnet reads "
                               f"({', '.join(CONTAINERS.values())})")
        try:
            container = av.open(f, format=fmt, options={"enable_drefs": "0"} if fmt == "mov" else {})
        except av_errors() as e:
            raise DatasetError(f"cannot read the video {shown(path)} ({why(e)}; is it damaged or truncated?)") from e
        check_streams(container, path)
        return container, f
    except BaseException:
        f.close()
        raise


def is_cover(stream: Any) -> bool:
    """Whether a PyAV video stream is an attached picture (cover art), not a video."""
    try:
        return bool(int(getattr(stream, "disposition", 0) or 0) & ATTACHED_PIC)
    except (TypeError, ValueError):
        return False


def check_streams(container: Any, where: Any, max_pixels: int = MAX_PIXELS) -> Any:
    """The first video stream of an open container that is not a cover picture (else the first), every stream that
    may be decoded (each that is not a cover picture, else the first) checked before a frame is decoded: its frame
    size against ``max_pixels``, its codec known; else :class:`DatasetError` (the container is closed)."""
    try:
        streams = list(container.streams.video)
        if not streams:
            raise DatasetError(f"{shown(where)} holds no video stream")
        videos = [s for s in streams if not is_cover(s)] or streams[:1]  # a cover is never decoded
        for stream in videos:
            cc = stream.codec_context
            if cc is None or not getattr(cc, "name", None):
                raise DatasetError(f"{shown(where)}: the video stream's codec is unknown to FFmpeg (codec id "
                                   f"{getattr(stream, 'codec_tag', '?')!r})")
            check_size(int(cc.width or 0), int(cc.height or 0), where, max_pixels)
        return videos[0]
    except BaseException:
        container.close()
        raise


def check_size(width: int, height: int, where: Any, max_pixels: int = MAX_PIXELS) -> None:
    """Refuse a frame of ``width`` x ``height`` above ``max_pixels`` (:class:`DatasetError`)."""
    if width * height > max_pixels:
        raise DatasetError(f"video {shown(where)} declares frames of {width}x{height} pixels, more than the limit "
                           f"of {max_pixels:,}")


def is_stream_name(name: str) -> bool:
    """Whether ``name`` names a live stream (a URL of :data:`STREAM_SCHEMES`, or ``/dev/videoN``)."""
    m = URL.match(name)
    return bool(DEVICE.fullmatch(name) or (m and m.group(1).lower() in STREAM_SCHEMES))


def open_stream(name: str, timeout: float = DEFAULT_TIMEOUT) -> tuple[Any, Any]:
    """``(container, None)``: a live stream (a URL or ``/dev/videoN``, named by the user) opened by PyAV with
    ``timeout`` seconds for opening and for each read; a video file's path opens as :func:`open_video_file`."""
    import av

    if not is_stream_name(name):
        m = URL.match(name)
        if m:
            raise ConfigError(f"{shown(name)[:120]}: the scheme {m.group(1)!r} is not a stream seqnet opens "
                              f"({', '.join(STREAM_SCHEMES)}, or /dev/videoN)")
        return open_video_file(Path(name))
    try:
        container = av.open(name, format="v4l2" if DEVICE.fullmatch(name) else None, timeout=(timeout, timeout))
    except av_errors() as e:
        raise DatasetError(f"cannot open the stream {shown(name)[:120]} ({why(e)}): no video came from it within "
                           f"{timeout:g} s (hint: --timeout)") from e
    check_streams(container, name)
    return container, None
