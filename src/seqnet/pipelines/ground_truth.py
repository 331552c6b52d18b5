"""The positions of the two traverses of ``seqnet dataset from-images``, one way per ground truth
(:data:`GROUND_TRUTH_SOURCES`, described in :mod:`seqnet.pipelines.from_images`); ``conf`` is its
:class:`~seqnet.pipelines.from_images.FromImagesConfig`."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ConfigError
from ..data.convert import match_names, read_positions_csv
from ..data.gps import check_zones, log_positions
from ..data.imagefolders import utm_positions
from ..data.sanity import check_frame_aligned
from ..describe.images import ImageList
from ..sources.bags.positions import is_bag, match_positions

Positions = tuple[np.ndarray, "np.ndarray | None", str, "str | None"]  # [N, P], sequence bounds, unit, frame


def _csv_positions(conf: Any, images: ImageList, source: str | Path, given: str | Path | None,
                   side: str) -> Positions:
    if given is None:
        raise ConfigError(f"ground truth 'csv' needs a positions CSV for the {side} (--{side[:3]}-csv FILE)")
    if conf.positions_format != "csv":  # a drive's position log (RobotCar ins.csv, KITTI oxts)
        xy, zone = log_positions(conf.positions_format, given, images.names, list(images.paths), conf.max_time_gap)
        return xy, None, "metres", f"UTM zone {zone}"
    names, pos, unit, bounds = read_positions_csv(given)
    idx = match_names(images.names, names, f"{given} vs the {side} images")
    return pos[idx], None if bounds is None else bounds[idx], unit, None


def _bag_positions(conf: Any, images: ImageList, source: str | Path, given: str | Path | None,
                   side: str) -> Positions:
    if given is None:
        raise ConfigError("ground truth 'bag' needs the positions topic (--positions-topic TOPIC)")
    if not is_bag(source):
        raise ConfigError(f"ground truth 'bag' reads the {side} positions from its bag, but {source} is not a ROS bag "
                          "(a .bag file or a ROS 2 bag directory)")
    found = images.positions  # read with the images, in one pass (list_images of the positions topic)
    if found is None:
        raise ConfigError(f"the {side} images of {source} were listed without their positions topic")
    stamps = np.array([frame.stamp for frame in images.paths], np.int64)  # bag frames (ImageList of a bag)
    return match_positions(stamps, found, conf.positions_tolerance, f"the {side} bag {source}"), None, "metres", \
        found.frame


def _frame_positions(conf: Any, images: ImageList, *_: object) -> Positions:
    return np.arange(len(images), dtype=np.float64)[:, None], None, "frames", None


GROUND_TRUTH_SOURCES: dict[str, Callable[..., Positions]] = {
    "csv": _csv_positions,
    "utm": lambda conf, images, *_: (utm_positions(images.names), None, "metres", None),
    "frames": _frame_positions,
    "positives": _frame_positions,  # explicit positives: frames as positions (windows, confidence)
    "bag": _bag_positions,
}
GROUND_TRUTHS = tuple(GROUND_TRUTH_SOURCES)


def both_positions(conf: Any, images: tuple[ImageList, ImageList], sources: tuple[str | Path, ...],
                   given: tuple[str | Path | None, str | Path | None]) -> tuple[Positions, Positions]:
    """The positions of the reference and the query, in one unit and frame (else :class:`ConfigError`); frame-aligned
    traverses must pair up (:func:`seqnet.data.sanity.check_frame_aligned`), checked before any image is described."""
    if conf.ground_truth == "frames":
        check_frame_aligned(images[0].names, images[1].names)
    ref, qry = (GROUND_TRUTH_SOURCES[conf.ground_truth](conf, im, src, g, side)
                for im, src, g, side in zip(images, sources, given, ("reference", "query"), strict=True))
    if ref[2] != qry[2] or (ref[3] is None) != (qry[3] is None):
        raise ConfigError(f"reference positions are in {ref[3] or ref[2]} but query positions in {qry[3] or qry[2]}"
                          " (hint: two traverses compare only in one frame)")
    if ref[3] is not None:
        check_zones(ref[3], qry[3])  # one UTM zone (an unknown zone, '?', is let through)
    return ref, qry
