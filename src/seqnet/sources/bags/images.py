"""A bag's image topic as an image source: :func:`bag_images` lists its frames in timestamp order.

Each frame is a :class:`BagFrame` (an :class:`~seqnet.describe.images.ImageItem`), named by its bag timestamp
(ns); it opens as a PIL image and is decoded from there as an image file is
(:func:`~seqnet.security.pictures.decode`), so a bag and a folder of the same images give the same descriptors.
Message types (:data:`IMAGE_TYPES`): ``sensor_msgs/Image`` with an encoding of
:data:`ENCODINGS` (rgb8, bgr8, mono8; others are refused by name) and ``sensor_msgs/CompressedImage`` (JPEG or
PNG, decoded with PIL). One reader stays open per bag; frames read in order cost one pass over the bag.
"""

from __future__ import annotations

import io
import weakref
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ...core.errors import ConfigError, DatasetError, ImageError
from ...security.pictures import COMPRESSED_FORMATS as COMPRESSED_PIL
from ...security.pictures import open_image
from ...security.text import shown
from . import positions as bags

ENCODINGS = {"rgb8": (3, False), "bgr8": (3, True), "mono8": (1, False)}  # channels, reversed (BGR)
COMPRESSED_FORMATS = ("jpeg", "jpg", "png")


def _raw_image(msg: Any, where: str) -> Any:
    """A ``sensor_msgs/Image`` as a PIL image (RGB or L) of its pixels."""
    from PIL import Image

    enc = str(msg.encoding).lower()
    if enc not in ENCODINGS:
        raise ImageError(f"{where}: image encoding {msg.encoding!r} is not supported; supported: "
                         f"{', '.join(ENCODINGS)} (hint: republish the topic as rgb8, or as a CompressedImage)")
    channels, reverse = ENCODINGS[enc]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, np.uint8)
    if step < w * channels or data.size < h * step:
        raise ImageError(f"{where}: {msg.encoding} image of {w}x{h} with step {step} needs {h * step} bytes of data "
                         f"(at least {w * channels} per row), the message holds {data.size}")
    px = data[: h * step].reshape(h, step)[:, : w * channels].reshape(h, w, channels)
    px = px[..., ::-1] if reverse else px
    return Image.fromarray(np.ascontiguousarray(px[..., 0] if channels == 1 else px), "L" if channels == 1 else "RGB")


def _compressed_image(msg: Any, where: str) -> Any:
    """A ``sensor_msgs/CompressedImage`` (JPEG / PNG) opened by PIL with those decoders only (decoded when loaded)."""
    fmt = str(msg.format).lower()
    if fmt and not any(f in fmt for f in COMPRESSED_FORMATS):
        raise ImageError(f"{where}: compressed image format {msg.format!r} is not supported; supported: "
                         f"{', '.join(COMPRESSED_FORMATS)} (compressedDepth and other formats are not images)")
    return open_image(io.BytesIO(bytes(np.asarray(msg.data, np.uint8))), COMPRESSED_PIL)


IMAGE_TYPES: dict[str, Callable[[Any, str], Any]] = {
    "sensor_msgs/msg/Image": _raw_image,
    "sensor_msgs/msg/CompressedImage": _compressed_image,
}


class BagImages:
    """The image messages of ``topic`` in the bag ``path``: :attr:`stamps` ``[N]`` (ns, in order), read by index;
    with a ``positions_topic``, its :attr:`positions` (:class:`~seqnet.sources.bags.positions.Positions`, read in
    the same pass).

    The reader opened here stays open for :meth:`read` (closed when the object goes away). A read of the frame
    after the last one read continues the pass; any other restarts it at that frame's timestamp."""

    def __init__(self, path: str | Path, topic: str, positions_topic: str | None = None) -> None:
        self.path, self.topic = Path(path), topic
        self.reader = bags.open_bag(path)
        self._finalizer = weakref.finalize(self, self.reader.close)
        self.conns = bags.connections(self.reader, topic, IMAGE_TYPES, "an image message", path)
        pos = [] if positions_topic is None else bags.position_connections(self.reader, positions_topic, path)
        stamps, read = [], []  # one pass: the image timestamps, and the position messages (small) whole
        for stamp, raw, msgtype in bags.messages(self.reader, self.conns + pos):
            if msgtype in IMAGE_TYPES:  # a topic's messages are of its one type (rosbags: else no type)
                stamps.append(stamp)
            else:
                read.append((stamp, raw, msgtype))
        self.stamps = np.array(stamps, np.int64)
        self.positions = (None if positions_topic is None else
                          bags.decode_positions(self.reader, read, positions_topic, path))
        self._pass: Iterator[tuple[int, Any, str]] | None = None
        self._next = -1  # index of the frame the pass yields next

    def __len__(self) -> int:
        return len(self.stamps)

    def _message(self, index: int) -> tuple[bytes, str]:
        if self._pass is None or index != self._next:
            stamp = int(self.stamps[index])
            self._pass = bags.messages(self.reader, self.conns, start=stamp)
            self._next = int(np.searchsorted(self.stamps, stamp, side="left"))  # the first of a shared stamp
        while True:
            try:
                _, raw, msgtype = next(self._pass)
            except StopIteration as e:
                raise DatasetError(f"{self.path} ended before frame {index} of {self.topic}; was it changed while "
                                   "being read?") from e
            self._next += 1
            if self._next - 1 == index:
                return raw, msgtype

    def open(self, index: int) -> Any:
        """Frame ``index`` as a PIL image (RGB or L for raw images; a compressed one is decoded when loaded)."""
        raw, msgtype = self._message(index)
        where = f"{self.path}:{self.topic}@{int(self.stamps[index])}"
        try:
            msg = bags.deserialize(self.reader, raw, msgtype, where)
        except DatasetError as e:
            raise ImageError(f"{e} (hint: --skip-corrupted leaves such images out)") from e
        try:  # the message definitions may come from the bag itself: a field may be missing or of another type
            return IMAGE_TYPES[msgtype](msg, where)
        except (AttributeError, TypeError, ValueError, OverflowError) as e:
            raise ImageError(f"{where}: the {msgtype} message is not as ROS defines it ({type(e).__name__}: "
                             f"{shown(' '.join(str(e).split()))[:160]}; hint: --skip-corrupted leaves such images "
                             "out)") from e

    def close(self) -> None:
        """Close the bag's reader (reads after it fail)."""
        self._finalizer()


class BagFrame:
    """One frame of a :class:`BagImages`: an :class:`~seqnet.describe.images.ImageItem` named by its timestamp."""

    __slots__ = ("bag", "index")

    def __init__(self, bag: BagImages, index: int) -> None:
        self.bag, self.index = bag, index

    @property
    def name(self) -> str:
        return str(int(self.bag.stamps[self.index]))

    @property
    def stamp(self) -> int:
        """The bag timestamp (ns)."""
        return int(self.bag.stamps[self.index])

    def open(self) -> Any:
        """The frame as a PIL image (decoded by :func:`~seqnet.security.pictures.decode`, as a file would be)."""
        return self.bag.open(self.index)

    def key(self) -> str:
        """Identity for provenance hashes: the resolved bag path, the topic and the timestamp."""
        return f"{self.bag.path.resolve()}:{self.bag.topic}@{self.name}"

    def __str__(self) -> str:
        return f"{self.bag.path}:{self.bag.topic}@{self.name}"

    def __repr__(self) -> str:
        return f"BagFrame({self})"

    def __deepcopy__(self, memo: dict) -> BagFrame:
        return self  # a reference into an open bag: copies (of a config holding it) share it


def image_topics(path: str | Path) -> str:
    """The image topics of a bag, for a hint: ``/cam (sensor_msgs/msg/Image, 30 messages), ...`` or ``none``."""
    reader = bags.open_bag(path)
    try:
        return bags.topic_list(reader, IMAGE_TYPES) or f"none (its topics: {bags.topic_list(reader) or 'none'})"
    finally:
        reader.close()


def bag_images(path: str | Path, topic: str | None,
               positions_topic: str | None = None) -> tuple[list[BagFrame], list[str], bags.Positions | None]:
    """``(frames, names, positions)`` of the image topic ``topic`` of the bag ``path``, in timestamp order, named by
    their timestamp (ns); ``positions``: those of ``positions_topic`` (None without one), read in the same pass."""
    if not topic:
        raise ConfigError(f"{path} is a ROS bag: name its image topic with --topic (its image topics: "
                          f"{image_topics(path)})")
    source = BagImages(path, topic, positions_topic)
    frames = [BagFrame(source, i) for i in range(len(source))]
    names = [f.name for f in frames]
    if len(set(names)) != len(names):
        dup = names[int(np.flatnonzero(np.diff(source.stamps) == 0)[0])]
        raise ImageError(f"two images of {topic} in {path} share the timestamp {dup}; frames are named and matched "
                         "by timestamp, so they cannot be told apart")
    return frames, names, source.positions
