"""Your own data in one step: two image folders + any ground truth → a dataset, described consistently.

``seqnet dataset from-images REF_DIR QUERY_DIR --method M --out DS`` describes both traverses with
ONE describer (one set of settings, one fit of PCA / NetVLAD clusters: on the reference images by
default, or on both, or on a split), so reference and query descriptors are comparable by
construction (their provenance is recorded), then attaches the ground truth, one of
:data:`GROUND_TRUTHS`:

* ``csv``: positions CSV files (an image-name column and ``easting,northing`` in metres, ``lat,lon`` in degrees
  (UTM metres, the query in the reference's zone) or ``frame``; optional ``sequence``), one per traverse, matched
  to the images by name; or, with
  ``positions_format`` ``robotcar-ins`` / ``kitti-oxts``, a drive's position log, the images matched
  to it by timestamp (:mod:`seqnet.data.gps`);
* ``utm``: UTM coordinates in the image names (``@<easting>@<northing>@...``);
* ``frames``: the two traverses are frame-aligned (query frame i ↔ reference frame i), positions are
  frame indices and the radius is in frames;
* ``positives``: explicit positives (``--positives FILE``: per query the matching reference indices);
  positions are frame indices (used for windows and the confidence's "same place");
* ``bag``: both traverses are ROS bags (``--topic`` their image topic) and the positions come from a topic of
  each (``--positions-topic``: NavSatFix to UTM metres, or odometry x, y), matched to each image by the nearest
  timestamp within ``positions_tolerance`` seconds (:mod:`seqnet.sources.bags.positions`).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from ..core.config import Config, check_choice, check_float, check_int
from ..core.errors import ConfigError, ImageError
from ..core.log import counted, logger
from ..data.convert import assemble_dataset
from ..data.gps import DEFAULT_MAX_GAP, POSITIONS_FORMATS
from ..data.io import save_dataset
from ..data.positives import Positives, read_positives
from ..data.sanity import review
from ..data.traverse import Dataset, Traverse
from ..describe import DescribeConfig, make_describer
from ..describe.images import ImageList, list_images, sides_size_mismatch
from ..describe.stage import describe_provenance
from ..security.locks import locked
from ..security.ownership import check_replaceable
from ..sources.bags.positions import DEFAULT_TOLERANCE, is_bag
from .descriptor_choice import CANDIDATES, candidate_describe, choose_on_val, evenly, proxy_scores
from .ground_truth import GROUND_TRUTHS, both_positions, check_true_matches

PROXY_SEQ_LEN = 5  # the window of the proxy's raw+seqmatch: the default L

FIT_ON = ("reference", "both")


@dataclasses.dataclass(frozen=True)
class FromImagesConfig(Config):
    """Settings of :func:`main`.

    Attributes:
        describe: how both traverses are described.
        fit_on: where PCA / NetVLAD clusters are fitted: ``reference``, ``both``, or a split name (never test)
            (the images of that split of both traverses; needs ``splits``).
        ground_truth: one of :data:`GROUND_TRUTHS`.
        radius: localisation radius (metres for UTM / CSV eastings, frames otherwise); inclusive. None with
            explicit positives: implied by them (:func:`seqnet.data.convert.positives_radius`).
        splits: named half-open index ranges ``{name: {"reference": (a, b), "query": (c, d)}}``.
        name: dataset name (None: the output directory's).
        pos_radius / neg_radius: training radii (stored as metadata).
        positions_format: how the ``csv`` ground truth's files are read (:data:`seqnet.data.gps.POSITIONS_FORMATS`).
        max_time_gap: seconds; an image farther than this from every sample of a position log is refused.
        positions_tolerance: ``bag``: the largest gap (seconds) between an image and its position message.
        pca: reduce the descriptors to this many dimensions by a PCA fitted on the ``train`` split only
            (:mod:`seqnet.pipelines.pca`; needs that split); None: no reduction.
        candidates: choose the describer among these methods on the ``val`` split (needs it) before describing,
            each with ``describe``'s other settings (:mod:`seqnet.pipelines.descriptor_choice`); empty: ``describe``.
    """

    describe: DescribeConfig = DescribeConfig()
    fit_on: str = "reference"
    ground_truth: str = "frames"
    radius: float | None = 1.0
    splits: dict | None = None
    name: str | None = None
    pos_radius: float | None = None
    neg_radius: float | None = None
    positions_format: str = "csv"
    max_time_gap: float = DEFAULT_MAX_GAP
    positions_tolerance: float = DEFAULT_TOLERANCE
    pca: int | None = None
    candidates: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        self._set("candidates", tuple(self.candidates))
        for name in self.candidates:
            check_choice("descriptor candidate", name, CANDIDATES)
        if self.candidates and "val" not in (self.splits or {}):
            raise ConfigError("choosing the descriptor (no --method) needs a val split to choose it on (never test): "
                              "give --split val=A:B[,C:D], or choose one with --method (e.g. pixels)")
        if self.pca is not None:
            self._set("pca", check_int("pca", self.pca, 1))
            if "train" not in (self.splits or {}):
                raise ConfigError("--pca fits the PCA on the train split only (never val or test): give it, e.g. "
                                  "--split train=A:B --split val=C:D --split test=E:F")
        check_choice("ground truth", self.ground_truth, GROUND_TRUTHS)
        check_choice("positions format", self.positions_format, POSITIONS_FORMATS)
        self._set("max_time_gap", check_float("max_time_gap", self.max_time_gap, 0.0, strict=True))
        self._set("positions_tolerance", check_float("positions tolerance", self.positions_tolerance, 0.0))
        if self.radius is not None:
            self._set("radius", check_float("radius", self.radius, 0.0, strict=True))
        if str(self.fit_on).lower() == "test":  # as --pca: never fitted on the test queries
            raise ConfigError(f"--fit-on {self.fit_on}: fitting the describer's PCA / NetVLAD clusters on the test "
                              "split's images makes its numbers optimistic; fit on the reference (the default) or "
                              "on a train split (--fit-on train)")
        if self.fit_on not in FIT_ON and self.fit_on not in (self.splits or {}):
            raise ConfigError(f"--fit-on {self.fit_on!r} is not one of {', '.join(FIT_ON)} or a split name "
                              f"({', '.join(self.splits or {}) or 'no splits given'})")


def _fit_images(conf: FromImagesConfig, ref: ImageList, qry: ImageList) -> list[Path] | None:
    """The images the describer's state is fitted on (None: the method fits nothing)."""
    ranges = _fit_ranges(conf, len(ref), len(qry))
    sides = {"reference": ref, "query": qry}
    return None if ranges is None else [sides[side].paths[i] for side, idx in ranges.items() for i in idx]


def _fit_ranges(conf: FromImagesConfig, n_ref: int, n_query: int) -> dict[str, range] | None:
    """The indices of the fitting images, reference then query, of ``conf.fit_on`` (None: nothing is fitted)."""
    if not conf.describe.needs_fit:
        return None
    if conf.fit_on in FIT_ON:
        return {"reference": range(n_ref), **({"query": range(n_query)} if conf.fit_on == "both" else {})}
    rng = conf.splits[conf.fit_on]  # NAME=A:B: queries A:B against the whole reference
    return {"reference": range(*rng.get("reference", (0, n_ref))), "query": range(*rng["query"])}


def main(conf: FromImagesConfig, reference: str | Path, query: str | Path, out: str | Path,
         positions: tuple[str | Path, str | Path] | None = None, positives: str | Path | None = None,
         overwrite: bool = False, topic: str | None = None, positions_topic: str | None = None) -> Path:
    """Describe the image folders (or list files, or ROS bags: their image ``topic``) ``reference`` and ``query``
    with one describer and write the dataset directory ``out`` (descriptors, positions, names, ground truth,
    provenance). ``positions``: the two positions CSVs (``csv``); ``positions_topic``: the bags' topic (``bag``).
    A dataset in which no query would have a true match is refused before any image is described."""
    bag_topic = positions_topic if conf.ground_truth == "bag" else None
    ref, qry = (list_images(src, topic, bag_topic if is_bag(src) else None) for src in (reference, query))
    if conf.ground_truth == "positives" and positives is None:
        raise ConfigError("ground truth 'positives' needs --positives FILE (JSON list of lists, CSV pairs or .npy)")
    given = positions or ((positions_topic, positions_topic) if conf.ground_truth == "bag" else (None, None))
    (pos_r, bounds_r, unit, frame), (pos_q, bounds_q, _, _) = both_positions(conf, (ref, qry), (reference, query),
                                                                             given)
    truth = read_positives(positives).check(len(qry), len(ref), str(positives)) if positives else None
    extra = {"images": {"reference": str(Path(reference).resolve()), "query": str(Path(query).resolve())},
             **({"topics": {"images": topic, "positions": positions_topic}} if topic else {})}
    return write_dataset(conf, (ref, qry), ((pos_r, bounds_r), (pos_q, bounds_q)), (unit, frame), out, overwrite,
                         truth, extra)


def positions_dataset(conf: FromImagesConfig, images: tuple[ImageList, ImageList],
                      positions: tuple[tuple[np.ndarray, np.ndarray | None], tuple[np.ndarray, np.ndarray | None]],
                      unit: str, truth: Positives | None, name: str) -> Dataset:
    """The dataset ``images`` will make, but for its descriptors (``[N, 1]`` ones: the ground truth's layout only):
    its true matches are checked and the descriptor chosen on it before any image is described."""
    ref, qry = images
    (pos_r, bounds_r), (pos_q, bounds_q) = positions
    ones = (np.ones((len(ref), 1), np.float32), np.ones((len(qry), 1), np.float32))
    return assemble_dataset(Traverse(ones[0], pos_r, ref.names, bounds_r, "reference"),
                            Traverse(ones[1], pos_q, qry.names, bounds_q, "query"), unit, conf.radius,
                            splits=conf.splits, name=name, positives=truth)


def choose_describer(conf: FromImagesConfig, images: tuple[ImageList, ImageList],
                     base: Dataset) -> tuple[DescribeConfig, dict]:
    """The describer :mod:`seqnet.pipelines.descriptor_choice` prefers among ``conf.candidates`` on the ``val``
    split of ``base`` (:func:`positions_dataset`): each candidate describes only the val images of both traverses
    (a fitted state fitted on :func:`_proxy_fit`'s images: no image of the test split); and the record of the
    choice."""
    ref, qry = images
    val, rng = base.split("val"), base.ranges("val")

    def score(dconf: DescribeConfig) -> dict:
        t0, fit = time.perf_counter(), _proxy_fit(conf.merge(describe=dconf), images, base)
        describer = make_describer(dconf.merge(fit=fit) if fit else dconf, fit or ref.paths)
        desc = {}
        for side, side_images in (("reference", ref), ("query", qry)):
            a, b = rng[side]
            desc[side], got = describer.describe(side_images.paths[a:b], side_images.names[a:b])
            if len(got) != b - a:
                raise ImageError(f"{counted(b - a - len(got), f'val {side} image')} could not be read: fix or "
                                 "remove them")
        described = dataclasses.replace(val, reference=val.reference.with_descriptors(desc["reference"]),
                                        query=val.query.with_descriptors(desc["query"]))
        return {**proxy_scores(described, PROXY_SEQ_LEN, dconf.device, t0=t0), "fit_images": len(fit)}

    def final_fit(dconf: DescribeConfig) -> int:
        return len(_fit_images(conf.merge(describe=dconf), ref, qry) or [])

    (a, b), (c, d) = rng["reference"], rng["query"]
    where = f"val queries {c}:{d} against reference {a}:{b}"
    before = (f"; these figures are before --pca {conf.pca} (the dataset written is reduced: what the PCA costs the "
              "chosen descriptor is measured after it is described)") if conf.pca is not None else ""
    dconf, record = choose_on_val({n: candidate_describe(conf.describe, n) for n in conf.candidates}, score, where,
                                  final_fit, before)
    return dconf, record | ({"before_pca": conf.pca} if conf.pca is not None else {})


def _proxy_fit(conf: FromImagesConfig, images: tuple[ImageList, ImageList], base: Dataset) -> list:
    """The images a candidate's state (``conf.describe``) is fitted on for the val proxy: its fitting images
    (``conf.fit_on``) that lie in the train or val split, at most
    :data:`~seqnet.pipelines.descriptor_choice.PROXY_FIT` evenly spaced (none when it fits nothing; the val images
    when none of them does), so that choosing reads no image that only the test split holds."""
    sides = {"reference": images[0], "query": images[1]}
    fitting = _fit_ranges(conf, len(images[0]), len(images[1]))
    if fitting is None:
        return []
    allowed: dict[str, set[int]] = {"reference": set(), "query": set()}
    for name in ("train", "val"):
        rng = base.ranges(name) if name in base.splits else None
        for side in allowed if rng else ():
            allowed[side].update(range(*rng[side]))
    fit = [sides[side].paths[i] for side, idx in fitting.items() for i in idx if i in allowed[side]]
    if not fit:
        val = base.ranges("val")
        fit = [sides[side].paths[i] for side in sides for i in range(*val[side])]
    return evenly(fit)


def _split_frames(rng: dict, n_ref: int, n_query: int) -> int:
    """The frames of both traverses in the split ``rng`` (``{"query": (a, b)}`` alone: the whole reference)."""
    (a, b), (c, d) = rng.get("reference", (0, n_ref)), rng["query"]
    return max(0, min(b, n_ref) - a) + max(0, min(d, n_query) - c)


def _before_describing(conf: FromImagesConfig, images: tuple[ImageList, ImageList],
                       positions: tuple[tuple[np.ndarray, np.ndarray | None], tuple[np.ndarray, np.ndarray | None]],
                       unit: tuple[str, str | None], truth: Positives | None, name: str) -> Dataset:
    """The checks before any image is described: a ``--pca`` the train split can fit, and queries with true
    matches (:func:`seqnet.pipelines.ground_truth.check_true_matches`: none is refused); the dataset's
    :func:`positions_dataset`."""
    if conf.pca is not None:
        from .pca import check_fit_frames

        check_fit_frames(conf.pca, _split_frames(conf.splits["train"], len(images[0]), len(images[1])), "train")
    base = positions_dataset(conf, images, positions, unit[0], truth, name)
    check_true_matches(base)
    return base


def write_dataset(conf: FromImagesConfig, images: tuple[ImageList, ImageList],
                  positions: tuple[tuple[np.ndarray, np.ndarray | None], tuple[np.ndarray, np.ndarray | None]],
                  unit: tuple[str, str | None], out: str | Path, overwrite: bool = False,
                  truth: Positives | None = None, extra: dict | None = None) -> Path:
    """Describe the reference and query ``images`` with one describer and write the dataset ``out``: their
    ``positions`` (``[N, P]`` and sequence bounds or None, each) in ``unit`` (``(unit, frame)``), explicit
    positives ``truth``, and ``extra`` metadata (what they were read from)."""
    ref, qry = images
    (pos_r, bounds_r), (pos_q, bounds_q) = positions
    with locked(Path(out)):
        if Path(out).exists() and any(Path(out).iterdir()) and not overwrite:
            raise ConfigError(f"output directory {out} exists and is not empty (use --overwrite to replace it)")
        check_replaceable(out, "dataset")  # before any work: a user's files are never replaced
        base = _before_describing(conf, images, positions, unit, truth, conf.name or Path(out).name)
        if conf.candidates:
            dconf, record = choose_describer(conf, images, base)
            conf, extra = conf.merge(describe=dconf, candidates=()), {**(extra or {}), "descriptor_choice": record}
        fit = _fit_images(conf, ref, qry)
        if mismatch := sides_size_mismatch(ref.paths, qry.paths, conf.describe.image_size):
            raise mismatch
        describer = make_describer(conf.describe.merge(fit=fit) if fit else conf.describe, fit or ref.paths)
        desc = {}
        for side, side_images in (("reference", ref), ("query", qry)):
            logger.info("describing %d %s images (%s)", len(side_images), side, conf.describe.label)
            desc[side], got = describer.describe(side_images.paths, side_images.names, spill=True)  # large: spilled
            if len(got) != len(side_images):
                missing = sorted(set(side_images.names) - set(got))
                raise ImageError(f"{counted(len(missing), side + ' image')} could not be read (first: "
                                 f"{missing[0]}); their ground truth would no longer line up: fix or remove them, "
                                 "then run again")
        prov = describe_provenance(describer.config, fit, desc["reference"], describer.seen_size)
        ds = assemble_dataset(
            Traverse(desc["reference"], pos_r, ref.names, bounds_r, "reference", prov),
            Traverse(desc["query"], pos_q, qry.names, bounds_q, "query", prov), unit[0], base.radius,
            splits=conf.splits, name=conf.name or Path(out).name, positives=truth,
            extra={"pos_radius": conf.pos_radius, "neg_radius": conf.neg_radius, "ground_truth": conf.ground_truth,
                   "describe": describer.config.to_dict() | {"fit": None}, "positions_frame": unit[1],
                   **(extra or {})})
        review(ds)  # the images' names were checked before describing; here the descriptors, splits, positions
        if conf.pca is not None:
            from .pca import reduce_measured, save_reduced

            return save_reduced(*reduce_measured(ds, conf.pca), out, overwrite=overwrite, quiet=True)
        return save_dataset(ds, out, overwrite=overwrite, quiet=True)  # the command says it, with more
