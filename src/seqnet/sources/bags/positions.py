"""ROS bags through ``rosbags`` (the optional extra ``seqnet[ros]``): opening, topics, and positions.

A *bag* is a ROS 1 ``.bag`` file or a ROS 2 bag directory (``metadata.yaml`` beside its ``.db3`` (sqlite3) or
``.mcap`` files; the ``.db3`` / ``.mcap`` file itself names its directory, and one without ``metadata.yaml``
beside it is read alone) — what ``rosbags``' ``AnyReader`` reads, without a ROS install. Its files are
checked before ``rosbags`` opens them (:mod:`seqnet.security.bagfiles`: no FIFO, ``metadata.yaml`` bounded and
typed, no bag compressed file by file), and whatever ``rosbags`` raises on a damaged bag, when it opens or
while messages are read, is one :class:`DatasetError` naming the bag. Every message is placed by its bag
timestamp (ns, the time it was recorded), which orders the frames and matches positions to images.

Positions come from a topic of one of :data:`POSITION_TYPES`: ``sensor_msgs/NavSatFix`` (latitude / longitude
to UTM metres with ``utm``, in the zone of the first fix; messages without a fix are left out) or
``nav_msgs/Odometry`` / ``geometry_msgs/PoseStamped`` (``position.x, y`` in metres, in their own frame). Each
image gets the position of the nearest position message in time (:func:`match_positions`), within a tolerance.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Container, Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ...core.errors import ConfigError, DatasetError
from ...core.log import logger
from ...security.bagfiles import check_bag
from ...security.text import shown

BAG_SUFFIXES = (".bag", ".db3", ".mcap")
ROS_HINT = "hint: pip install 'seqnet[ros]' (the pure-Python package rosbags)"
DEFAULT_TOLERANCE = 0.5  # seconds between an image and the nearest position message


def is_bag(path: str | Path) -> bool:
    """Whether ``path`` is a bag: a ``.bag`` / ``.db3`` / ``.mcap`` file or a directory with ``metadata.yaml``."""
    p = Path(path)
    return (p.is_file() and p.suffix.lower() in BAG_SUFFIXES) or (p.is_dir() and (p / "metadata.yaml").is_file())


def open_bag(path: str | Path) -> Any:
    """An open ``rosbags.highlevel.AnyReader`` of the bag ``path`` (close it with ``.close()``).

    Bags without embedded message definitions (ROS 2 before Iron) are read with the ROS 2 Humble types."""
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError as err:
        raise ConfigError(f"reading ROS bags needs the package rosbags ({ROS_HINT})") from err
    root = check_bag(path)
    try:
        reader = AnyReader([root], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as e:  # noqa: BLE001 - rosbags and sqlite / MCAP / lz4 / bz2 under it raise many kinds
        raise DatasetError(f"cannot read the bag {root} ({_why(e)}; rosbags reads ROS 1 .bag files and ROS 2 bag "
                           "directories or storage files, sqlite3 or MCAP)") from e
    return reader


def _why(e: BaseException) -> str:
    return f"{type(e).__name__}: {shown(' '.join(str(e).split()))[:200]}"


def topic_list(reader: Any, types: Container[str] | None = None) -> str:
    """``/a (sensor_msgs/msg/Image, 12 messages), ...``: the topics of an open bag (those carrying one of
    ``types``, when given), for error messages."""
    return ", ".join(f"{shown(name)[:120]} ({shown(info.msgtype)[:80]}, {info.msgcount} messages)"
                     for name, info in topics(reader).items() if types is None or info.msgtype in types)


def topics(reader: Any) -> dict[str, Any]:
    """The topics of an open bag (``AnyReader.topics``); a damaged index (a topic without a name) is a
    :class:`DatasetError`."""
    try:
        return dict(reader.topics)
    except Exception as e:  # noqa: BLE001 - rosbags sorts and sums what the bag's index holds
        raise DatasetError(f"cannot read the topics of the bag {getattr(reader, 'paths', ['?'])[0]} ({_why(e)}; "
                           "is it damaged?)") from e


def connections(reader: Any, topic: str, types: Mapping[str, Any], what: str, path: str | Path) -> list:
    """The connections of ``topic`` in an open bag, which must carry one of the message ``types``; else
    :class:`DatasetError` naming the bag's topics (a missing topic) or the type found and the valid ones."""
    info = topics(reader).get(topic)
    if info is None:
        raise DatasetError(f"the bag {path} has no topic {topic!r}; its topics: {topic_list(reader) or 'none'}")
    if info.msgtype not in types:
        raise DatasetError(f"topic {shown(topic)} of the bag {path} carries {shown(info.msgtype)[:80]}, not {what} "
                           f"({', '.join(types)})")
    if not info.msgcount:
        raise DatasetError(f"topic {topic} of the bag {path} has no messages")
    return list(info.connections)


def messages(reader: Any, conns: list, start: int | None = None) -> Iterator[tuple[int, Any, str]]:
    """``(timestamp ns, raw bytes, message type)`` of the connections ``conns``, in timestamp order (from ``start``);
    a bag damaged past its index (a chunk, a row, a record) is a :class:`DatasetError` where it is met."""
    try:
        for conn, stamp, raw in reader.messages(conns, start=start):
            yield int(stamp), raw, conn.msgtype
    except Exception as e:  # noqa: BLE001 - rosbags' errors and those of the libraries under it have no common base
        where = getattr(reader, "paths", ["the bag"])[0]
        raise DatasetError(f"cannot read the messages of the bag {where} ({_why(e)}; is it damaged or "
                           "truncated?)") from e


def deserialize(reader: Any, raw: bytes, msgtype: str, where: str) -> Any:
    """One message of an open bag, decoded; :class:`DatasetError` when its bytes do not decode."""
    try:
        return reader.deserialize(raw, msgtype)
    except Exception as e:  # rosbags raises its own errors and struct / index errors on truncated data
        raise DatasetError(f"cannot decode the {msgtype} message {where} ({type(e).__name__}: {e})") from e


# ----------------------------------------------------------------------------- positions


@dataclasses.dataclass(frozen=True)
class Positions:
    """Positions read from a bag topic: ``stamps [M]`` (ns, increasing), ``xy [M, 2]`` metres, and the frame they
    are in (``UTM zone 32V`` or ``odometry frame 'odom'``): two traverses compare only in one frame."""

    stamps: np.ndarray
    xy: np.ndarray
    frame: str


def _navsat(msgs: list[Any]) -> tuple[np.ndarray, np.ndarray, str]:
    """``(kept [M] bool, xy [K, 2] UTM metres, frame)`` of NavSatFix messages: those with a fix and finite lat/lon."""
    from ...data.utm import latlon_to_utm

    lat = np.array([m.latitude for m in msgs], np.float64)
    lon = np.array([m.longitude for m in msgs], np.float64)
    kept = np.array([m.status.status >= 0 for m in msgs]) & np.isfinite(lat) & np.isfinite(lon)
    if not kept.any():
        return kept, np.zeros((0, 2)), "UTM"
    xy, zone = latlon_to_utm(lat[kept], lon[kept], "NavSatFix")  # utm: a dependency of seqnet
    return kept, xy, f"UTM zone {zone}"


def _pose_xy(pose_of: Callable[[Any], Any]) -> Callable[[list[Any]], tuple[np.ndarray, np.ndarray, str]]:
    def read(msgs: list[Any]) -> tuple[np.ndarray, np.ndarray, str]:
        xy = np.array([[pose_of(m).position.x, pose_of(m).position.y] for m in msgs], np.float64).reshape(-1, 2)
        kept = np.isfinite(xy).all(axis=1)
        frame = msgs[0].header.frame_id if msgs else ""
        return kept, xy[kept], f"odometry frame {frame!r}"

    return read


POSITION_TYPES: dict[str, Callable[[list[Any]], tuple[np.ndarray, np.ndarray, str]]] = {
    "sensor_msgs/msg/NavSatFix": _navsat,
    "nav_msgs/msg/Odometry": _pose_xy(lambda m: m.pose.pose),
    "geometry_msgs/msg/PoseStamped": _pose_xy(lambda m: m.pose),
}


def read_positions(path: str | Path, topic: str) -> Positions:
    """The positions of ``topic`` in the bag ``path`` (one of :data:`POSITION_TYPES`), in timestamp order."""
    reader = open_bag(path)
    try:
        conns = position_connections(reader, topic, path)
        return decode_positions(reader, list(messages(reader, conns)), topic, path)
    finally:
        reader.close()


def position_connections(reader: Any, topic: str, path: str | Path) -> list:
    """The connections of the position ``topic`` of an open bag (:func:`connections` of :data:`POSITION_TYPES`)."""
    return connections(reader, topic, POSITION_TYPES, "a position message", path)


def decode_positions(reader: Any, read: list[tuple[int, bytes, str]], topic: str, path: str | Path) -> Positions:
    """The positions of the messages ``read`` (``(timestamp ns, raw, message type)`` of :func:`messages`, in order)
    of the position ``topic`` of an open bag: decoded, without a fix or a finite position left out."""
    stamps = [stamp for stamp, _, _ in read]
    msgs = [deserialize(reader, raw, msgtype, f"at {stamp} on {topic} of {path}") for stamp, raw, msgtype in read]
    if not msgs:
        raise DatasetError(f"topic {shown(topic)} of the bag {path} has no message that could be read (its index "
                           "lists some: is the bag damaged?)")
    msgtype = read[0][2]
    try:  # the message definitions may come from the bag itself: a field may be missing or of another type
        kept, xy, frame = POSITION_TYPES[msgtype](msgs)
    except (AttributeError, TypeError, ValueError, OverflowError) as e:
        raise DatasetError(f"the {msgtype} messages of {shown(topic)} in the bag {path} are not as ROS "
                           f"defines them ({_why(e)})") from e
    if not kept.all():
        logger.warning("%s of %s: %d of %d position messages have no fix or a non-finite position; left out",
                       topic, path, int((~kept).sum()), len(kept))
    if not kept.any():
        raise DatasetError(f"topic {topic} of the bag {path} has no usable position (no fix in any of its "
                           f"{len(kept)} messages)")
    return Positions(np.asarray(stamps, np.int64)[kept], xy, frame)


def match_positions(stamps: np.ndarray, positions: Positions, tolerance: float, what: str) -> np.ndarray:
    """``[N, 2]``: for each image timestamp ``stamps [N]`` (ns) the position of the nearest position message.

    Raises :class:`DatasetError` naming the first image farther than ``tolerance`` seconds from every position
    message (a position that far off would be a wrong ground truth, not an approximate one)."""
    from ...data.timematch import nearest_within

    stamps = np.asarray(stamps, np.int64)
    nearest = nearest_within(positions.stamps, stamps, tolerance, lambda bad, gap: (
        f"{bad.size} of {len(stamps)} images of {what} have no position message within {tolerance:g} s (first: "
        f"image {bad[0]}, timestamp {int(stamps[bad[0]])}, {gap[bad[0]]:.3f} s from the nearest); hint: a larger "
        "--positions-tolerance, or check the positions topic"), scale=1e9)
    return positions.xy[nearest]
