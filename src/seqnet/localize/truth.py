"""Ground truth of a query streamed from a ROS bag: the positions of one of its topics, checked to be in the
frame of the map's positions.

``seqnet localize --map MAP --query RUN.bag --topic T --positions-topic P``: each frame of ``T`` takes the
position of the message of ``P`` nearest in time
(:func:`seqnet.sources.bags.positions.match_positions`, within a tolerance;
``sensor_msgs/NavSatFix`` as UTM metres, ``nav_msgs/Odometry`` / ``geometry_msgs/PoseStamped`` as their x, y).
Those positions are compared with the map's only when both are in one frame (:func:`check_frame`): the map's
positions must be metres in a frame it records (``positions_frame``, written by ``seqnet dataset from-images``
for bags and position logs, and carried into index maps), the same UTM zone (number and hemisphere) or the same
odometry frame. A map that records no frame is refused: a ground truth in another frame would be a wrong number.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.errors import ConfigError
from ..core.log import logger
from ..data.utm import frame_zone
from ..security.text import shown
from ..sources.bags.positions import match_positions
from ..sources.tracks.metres import XY_FRAME
from .track import Sampling, map_sampling

if TYPE_CHECKING:
    from ..describe.images import ImageList



@dataclasses.dataclass(frozen=True)
class MapFrame:
    """Where a map's positions are: their ``unit`` (``metres`` / ``frames``) and ``frame`` (``UTM zone 32V``,
    ``odometry frame 'odom'``; None: not recorded); and, for a map made from a video, how its frames were sampled
    (``sampling``, :func:`seqnet.localize.track.map_sampling`)."""

    unit: str | None
    frame: str | None
    sampling: Sampling | None = None

    @classmethod
    def of(cls, meta: Mapping[str, Any]) -> MapFrame:
        """The frame recorded in a dataset's metadata or an index map's ``source`` (text, else unknown)."""
        unit, frame = meta.get("position_unit"), meta.get("positions_frame")
        return cls(unit if isinstance(unit, str) else None, frame if isinstance(frame, str) else None,
                   map_sampling(meta))


def query_positions(images: ImageList, tolerance: float, source: str | Path) -> np.ndarray:
    """``[N, 2]``: the position of each bag frame of ``images`` (listed with their positions topic), the message
    nearest in time within ``tolerance`` seconds (else :class:`~seqnet.core.errors.DatasetError`, with a count)."""
    if images.positions is None:
        raise ConfigError(f"the images of {source} were listed without a positions topic")
    stamps = np.array([frame.stamp for frame in images.paths], np.int64)  # bag frames: their timestamps
    return match_positions(stamps, images.positions, tolerance, f"the query bag {source}")


def _utm(frame: str) -> tuple[int, bool] | None:
    """``(zone number, northern hemisphere)`` of ``UTM zone 32V``; None for another frame or an unknown zone."""
    zone = frame_zone(frame)
    return None if zone is None else (zone[0], zone[1] >= "N")


def same_frame(a: str, b: str) -> bool:
    """Whether positions in frames ``a`` and ``b`` compare: one UTM zone and hemisphere (the band letter does not
    change the metres), or one named frame; an unknown UTM zone compares with none."""
    if a.startswith("UTM") or b.startswith("UTM"):
        za, zb = _utm(a), _utm(b)
        return za is not None and za == zb
    return a == b


def check_frame(mf: MapFrame, frame: str, map_path: str | Path, topic: str) -> None:
    """Refuse (:class:`ConfigError`) positions in ``frame`` (of the query's ``topic``) that do not compare with the
    map's (:class:`MapFrame`): not metres, a frame the map does not record, or another frame."""
    where = f"positions of {shown(topic)[:120]} ({frame})"
    if mf.unit != "metres":
        raise ConfigError(f"the map {map_path} has positions in {mf.unit or 'an unknown unit'}, not metres, so the "
                          f"{where} cannot be compared with them (a map built from frame-aligned traverses or "
                          "explicit positives has no metric positions)")
    if mf.frame is None and frame == XY_FRAME:  # a CSV's x, y metres against a map of a CSV's x, y metres
        logger.warning("the map %s does not record the frame of its positions (a positions CSV's easting/northing or "
                       "x/y), nor does %s: its x, y metres are taken to be in the map's frame, unchecked", map_path,
                       shown(topic)[:120])
        return
    if mf.frame is None or (mf.frame.startswith("UTM") and _utm(mf.frame) is None):  # "UTM zone ?": a log's
        raise ConfigError(f"the map {map_path} does not record the frame of its positions (UTM zone or odometry "
                          f"frame), so the {where} cannot be checked to be in it; hint: give the track in the map's "
                          "own metres (columns time,x,y or time,easting,northing), or build the map's dataset from "
                          "lat,lon positions (a CSV with lat,lon columns, a GPS track, --positions-topic), which "
                          "records the UTM zone")
    if not same_frame(mf.frame, frame):
        raise ConfigError(f"the map {map_path} has positions in {shown(mf.frame)[:80]}, the {where}: positions in "
                          "two frames are not comparable")
