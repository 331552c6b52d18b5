"""The positions of the two traverses of ``seqnet dataset from-images``, one way per ground truth
(:data:`GROUND_TRUTH_SOURCES`, described in :mod:`seqnet.pipelines.from_images`); ``conf`` is its
:class:`~seqnet.pipelines.from_images.FromImagesConfig`."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ConfigError, DatasetError
from ..core.log import logger
from ..data.convert import agreed_kinds, match_names, read_positions_table, sequence_bounds, warn_reordered
from ..data.gps import ZONE_HINT, check_zones, log_positions
from ..data.imagefolders import utm_positions
from ..data.sanity import check_frame_aligned
from ..data.sanity.route import radius_hint, spacing_share
from ..data.spacing import DEGREES_HINT, looks_like_degrees
from ..data.traverse import Dataset
from ..data.utm import latlon_pair, mixed_frames
from ..describe.images import ImageList
from ..sources.bags.positions import is_bag, match_positions

Positions = tuple[np.ndarray, "np.ndarray | None", str, "str | None"]  # [N, P], sequence bounds, unit, frame


def _csv_positions(conf: Any, images: ImageList, source: str | Path, given: str | Path | None,
                   side: str, kind: str | None = None) -> Positions:
    if given is None:
        raise ConfigError(f"ground truth 'csv' needs a positions CSV for the {side} (--{side[:3]}-csv FILE)")
    if conf.positions_format != "csv":  # a drive's position log (RobotCar ins.csv, KITTI oxts)
        pos, unit, zone = log_positions(conf.positions_format, given, images.names, list(images.paths),
                                        conf.max_time_gap)  # lat/lon: made metres with the other side's, below
        return pos, None, unit, f"UTM zone {zone}" if unit == "metres" else None
    table = read_positions_table(given, kind)  # kind: of positions, both CSVs' one (agreed_kinds)
    idx = match_names(images.names, table.names, f"{given} vs the {side} images")  # each image's CSV row
    warn_reordered(idx, images.names, table.names, f"the order of the {side} images of {source}",
                   "if the CSV's order is the route's, give the images as a list file (one path per line) in that "
                   "order")
    bounds = None if table.keys is None else sequence_bounds([table.keys[i] for i in idx], str(table.column))
    return table.positions[idx], bounds, table.unit, None  # sequences: runs of the images' order, as the positions


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
        note = check_frame_aligned(images[0].names, images[1].names)
        if note:
            logger.info("%s", note)
    kinds: tuple[str | None, ...] = (None, None)
    if conf.ground_truth == "csv" and conf.positions_format == "csv" and None not in given:
        kinds = agreed_kinds((str(given[0]), str(given[1])))  # lat/lon and x/y in one CSV: the kind both have
    ref, qry = (GROUND_TRUTH_SOURCES[conf.ground_truth](conf, im, src, g, side, *([k] if k else []))
                for im, src, g, side, k in zip(images, sources, given, ("reference", "query"), kinds, strict=True))
    if ref[2] == qry[2] == "degrees":  # lat/lon CSVs or logs: UTM metres, the query in the reference's zone
        r, q, frame = latlon_pair(ref[0], qry[0], (str(given[0]), str(given[1])))
        ref, qry = (r, ref[1], "metres", frame), (q, qry[1], "metres", frame)
    if ref[2] != qry[2] or (ref[3] is None) != (qry[3] is None):
        raise ConfigError(mixed_frames(ref[3] or ref[2], qry[3] or qry[2], "positions sources"))
    if ref[3] is not None:
        logs = conf.ground_truth == "csv" and conf.positions_format != "csv"  # position logs: their way out
        check_zones(ref[3], qry[3], ZONE_HINT if logs else None)  # one UTM zone (an unknown zone, '?', let through)
    if conf.ground_truth == "csv" and ref[2] == qry[2] == "frames" and len(ref[0]) and len(qry[0]):
        frame_starts(float(ref[0].min()), float(qry[0].min()), (str(given[0]), str(given[1])))
    return ref, qry


def frame_starts(ref: float, qry: float, files: tuple[str, str]) -> None:
    """Say when the frame columns of the two CSVs ``files`` start at different numbers (``ref``, ``qry``): a
    warning when one starts at 0 and the other at 1 (one file numbered from 1: every query's true references
    shift by one frame, silently), else a note (a query over part of the route)."""
    if ref == qry:
        return
    said = f"the reference frames ({files[0]}) start at {ref:g}, the query frames ({files[1]}) at {qry:g}"
    if {ref, qry} == {0.0, 1.0}:
        logger.warning("%s: one file numbered from 1? frame i of the query is taken to be at the place of frame i "
                       "of the reference, so every true match moves by one frame (hint: number both files from 0)",
                       said)
    else:
        logger.info("%s (frame i of the query is at the place of frame i of the reference)", said)


FEW_MATCHES = 0.5  # a dataset (or named split) in which fewer queries than this share have a true match is warned
TRUNCATED = 0.1  # explicit positives whose last listed query leaves this share of the queries after it: warned


def _matched(ds: Dataset) -> np.ndarray:
    """``[M]`` bool: whether each query of ``ds`` has a true match, by the one ground truth of evaluation."""
    from ..metrics.recall import ground_truth

    return ground_truth(ds.query.positions, ds.reference.positions, ds.radius, ds.positives,
                        require=False).has_positive()


def check_true_matches(ds: Dataset) -> str | None:
    """Whether ``ds``'s queries have true matches, by the one ground truth of evaluation
    (:func:`seqnet.metrics.recall.ground_truth`): none is a :class:`DatasetError` (the dataset is unusable), fewer
    than :data:`FEW_MATCHES` of them a warning line (logged, and returned), each naming the likely cause
    (:func:`mismatch_hint`); None when most queries have one. Each named split with fewer than
    :data:`FEW_MATCHES` is warned about too, and explicit positives that stop well before the last query
    (:func:`truncated_positives`)."""
    has = _matched(ds)
    n, m = int(has.sum()), len(ds.query)
    truncated_positives(ds, has)
    if m == 0 or n >= FEW_MATCHES * m:
        _check_splits(ds)
        return None
    what = "an explicit positive" if ds.positives is not None else (f"a reference within the radius "
                                                                       f"{ds.radius:g} {ds.position_unit}")
    if n == 0:
        raise DatasetError(f"{ds.name}: none of the {m} queries has {what}, so every Recall@K would be undefined; "
                           f"nothing written: {mismatch_hint(ds, n)}")
    line = f"{ds.name}: only {n} of {m} queries ({100 * n / m:.0f}%) have {what}: {mismatch_hint(ds, n)}"
    logger.warning("%s", line)
    return line


def _check_splits(ds: Dataset) -> None:
    """Warn about each named split of ``ds`` in which fewer than :data:`FEW_MATCHES` of the queries have a true
    match (against the split's references), when the dataset as a whole has enough."""
    for name in ds.splits:
        sub = ds.split(name)
        n, m = int(_matched(sub).sum()), len(sub.query)
        if m and 0 < n < FEW_MATCHES * m:  # none at all: data.sanity's unmatched_splits says it, with its cause
            a, b = ds.splits[name]["query"]
            logger.warning("%s: split %s (queries %d:%d): only %d of %d queries (%.0f%%) have a true match, so its "
                           "Recall@K is over those %d only: %s", ds.name, name, a, b, n, m, 100 * n / m, n,
                           mismatch_hint(sub, n, ds))


def truncated_positives(ds: Dataset, has: np.ndarray) -> str | None:
    """A warning line (logged, and returned) when ``ds``'s explicit positives give nearly every query up to some
    query a match and none after it, for at least :data:`TRUNCATED` of the queries (and 5): a positives file cut
    short (a truncated export) reads as that many queries without a match; None otherwise."""
    m = len(has)
    if ds.positives is None or not has.any():
        return None
    last = int(np.flatnonzero(has)[-1])
    tail = m - 1 - last
    if tail < max(5, TRUNCATED * m) or has[:last + 1].mean() < 0.9:
        return None
    line = (f"{ds.name}: the explicit positives give queries 0..{last} a match ({int(has.sum())} of them) and none "
            f"of the last {tail} of {m} queries: a truncated positives file? (hint: check that the file lists the "
            f"queries up to {m - 1}; queries past the end of the reference's route have none)")
    logger.warning("%s", line)
    return line


def below_spacing(r: np.ndarray, radius: float, unit: str, near: float) -> str | None:
    """Why few queries have a reference within ``radius``, when the queries lie among the reference's frames (their
    median distance ``near`` to the nearest is within the spacing of the reference positions ``r [N, P]``) and the
    radius is below :data:`~seqnet.data.sanity.route.SPARSE` times that spacing: the radius is too small (a radius
    ten times smaller than the spacing or more: None, another unit is likelier;
    :func:`~seqnet.data.sanity.route.spacing_share`)."""
    found = spacing_share(r, radius, low=0.1)
    if found is None or near > found[1]:
        return None
    share, gap = found
    return (f"{share} the reference's frame spacing ({gap:.3g} {unit} between neighbouring frames, median): the "
            f"queries lie between its frames, out of a radius this small ({radius_hint(gap)})")


def mismatch_hint(ds: Dataset, matched: int, whole: Dataset | None = None) -> str:
    """Why few queries of ``ds`` have a true match: how far the nearest references are against the radius, and
    the likely cause (a radius below the reference's frame spacing, but not ten times, while the queries lie among
    its frames: the radius; one traverse's two position columns swapped, when swapping them gives more queries a match;
    degrees; frames numbered from different starts, by the first frames of ``whole`` when ``ds`` is a split of it;
    else swapped columns or a radius in another unit)."""
    if ds.positives is not None:
        return "hint: check the positives file (per query its matching reference indices, counted from 0)"
    from scipy.spatial import cKDTree

    from ..metrics.recall import has_positive

    q, r, unit = ds.query.positions, ds.reference.positions, ds.position_unit
    if not len(r):
        return "hint: the reference holds no image"
    near = cKDTree(r).query(q, k=1)[0]
    said = (f"the nearest reference to any query is {float(near.min()):.1f} {unit} away (median over the queries "
            f"{float(np.median(near)):.1f} {unit}), the radius is {ds.radius:g} {unit}")
    tight = below_spacing(r, ds.radius, unit, float(np.median(near)))
    if tight:
        return f"{said}, {tight}"
    if q.shape[1] == 2:
        swapped = int(has_positive(q[:, ::-1], r, ds.radius).sum())
        if swapped > matched and swapped >= FEW_MATCHES * len(q):
            return (f"{said}; with one traverse's two position columns swapped {swapped} of {len(q)} queries would "
                    "have one: easting/northing (or x/y, lat/lon) swapped in the reference's or the query's "
                    "positions? (hint: swap the two column names in its header)")
    if looks_like_degrees(np.concatenate([r, q])):
        return f"{said}; {DEGREES_HINT}"
    first_r, first_q = (float(t.positions.min()) for t in ((whole or ds).reference, (whole or ds).query))
    if unit == "frames" and first_r != first_q:
        return (f"{said}: the two files number their frames differently (reference from {first_r:g}, query from "
                f"{first_q:g})? (hint: number both from 0, frame i of the query at the place of frame i of the "
                "reference, or give positions in metres)")
    if unit == "frames":
        return f"{said}: its queries lie where the reference has few frames (hint: check the split's ranges)"
    return (f"{said}: positions swapped (easting/northing, lat/lon), the radius in another unit, or traverses in "
            "different coordinate frames? (hint: check both position files and the radius)")
