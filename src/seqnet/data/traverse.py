"""Data model: traverses and datasets, and the seqnet dataset directory format.

A *traverse* is one pass along a route: single-image descriptors ``[N, D]``, positions ``[N, 1]``
(frame numbers) or ``[N, 2]`` (UTM easting/northing, metres), optional image names and optional
sequence bounds ``[N, 2]`` (for each image, the half-open frame range ``[start, end)`` of the
sequence it belongs to). A *dataset* pairs a reference and a query traverse with a localisation
radius and optional train/val/test index ranges.

Directory format (read and written by :mod:`seqnet.data.io`; see docs/dataset_format.md)::

    DIR/dataset.json            {"format": "seqnet-dataset/1", "radius": 1.0, ...}
    DIR/reference/descriptors.npy | descriptors.h5   [N, D] float32 (h5: dataset "descriptors")
    DIR/reference/positions.npy | positions.csv      [N, 1] or [N, 2]
    DIR/reference/names.txt                          optional, one image name per line
    DIR/reference/seq_bounds.npy                     optional, [N, 2] int
    DIR/query/...                                    same layout
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import DatasetError
from ..core.log import logger
from .orientation import OVERRIDE_ENV, OVERRIDE_KEY, overridden, read_square
from .orientation import hint as orientation_hint
from .positives import Positives, as_positives
from .validation import validate_traverse

FORMAT = "seqnet-dataset/1"
POSITION_UNITS = ("frames", "metres")
SPLIT_NAMES = ("train", "val", "test")
DESCRIPTOR_FILES = ("descriptors.npy", "descriptors.h5", "descriptors.hdf5")
POSITION_FILES = ("positions.npy", "positions.csv", "positions.txt")


@dataclasses.dataclass
class Traverse:
    """One pass along a route.

    Attributes:
        descriptors: ``[N, D]`` float32 single-image descriptors (may be memory-mapped).
        positions: ``[N, 1]`` frame numbers or ``[N, 2]`` easting/northing in metres.
        names: optional ``N`` image names.
        seq_bounds: optional ``[N, 2]`` int, half-open sequence range of each image.
        name: label used in messages.
        provenance: how the descriptors were made (:mod:`seqnet.core.provenance`), or None when unknown.
    """

    descriptors: np.ndarray
    positions: np.ndarray
    names: list[str] | None = None
    seq_bounds: np.ndarray | None = None
    name: str = "traverse"
    provenance: dict | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.descriptors, np.ndarray):
            try:
                self.descriptors = np.asarray(self.descriptors)
            except (TypeError, ValueError) as e:
                raise DatasetError(f"{self.name}: descriptors are not an [N, D] array ({e})") from e
        try:
            self.positions = np.asarray(self.positions, dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise DatasetError(f"{self.name}: positions must be numbers ({e})") from e
        if self.positions.ndim == 1:
            self.positions = self.positions[:, None]
        if self.seq_bounds is not None:
            b = np.asarray(self.seq_bounds)
            if b.size and b.dtype.kind not in "iu":
                raise DatasetError(f"{self.name}: seq_bounds must hold integers, got dtype {b.dtype}")
            self.seq_bounds = b.astype(np.int64, copy=False)
        validate_traverse(self)

    def __len__(self) -> int:
        return int(self.descriptors.shape[0])

    def __repr__(self) -> str:  # one line: the dataclass's printed every name (31,702 characters for 1000 frames)
        d, p = self.descriptors, self.positions
        what = "frame numbers" if p.ndim == 2 and p.shape[1] == 1 else f"positions {list(p.shape)}"
        extra = [x for x, has in (("names", self.names is not None), ("seq_bounds", self.seq_bounds is not None),
                                  ("provenance", self.provenance is not None)) if has]
        return (f"Traverse({self.name!r}: {len(d)} images, D={d.shape[1] if d.ndim == 2 else '?'} {d.dtype}, "
                f"{what}{''.join(', ' + x for x in extra)})")

    @property
    def dim(self) -> int:
        """Descriptor dimension D."""
        return int(self.descriptors.shape[1])

    def subset(self, start: int, stop: int) -> Traverse:
        """Frames ``[start, stop)`` as a new traverse; sequence bounds are clipped to the range."""
        n = len(self)
        if not (0 <= start < stop <= n):
            raise DatasetError(
                f"{self.name}: index range {start}:{stop} is outside 0:{n} or empty "
                "(hint: ranges are half-open START:STOP with 0 <= START < STOP <= number of images)"
            )
        bounds = None
        if self.seq_bounds is not None:
            bounds = np.clip(self.seq_bounds[start:stop], start, stop) - start
        # a part of a checked traverse is checked: no second scan of its descriptors for NaN
        part = object.__new__(Traverse)
        part.descriptors, part.positions = self.descriptors[start:stop], self.positions[start:stop]
        part.names = None if self.names is None else self.names[start:stop]
        part.seq_bounds, part.name, part.provenance = bounds, self.name, self.provenance
        return part

    def with_descriptors(self, descriptors: np.ndarray, provenance: dict | None = None) -> Traverse:
        """Same traverse (positions, names, bounds) with other descriptors ``[N, D']`` (and their provenance)."""
        return dataclasses.replace(self, descriptors=descriptors, provenance=provenance)


@dataclasses.dataclass
class Dataset:
    """A reference traverse, a query traverse and a localisation radius.

    ``splits`` maps a split name to ``{"reference": (start, stop), "query": (start, stop)}``; a split given
    as ``{"query": (start, stop)}`` alone selects queries against the whole reference (the map stays whole).
    ``extra`` holds any other metadata (positive/negative training radii, preset, source, ...).
    ``positives`` (optional) is explicit ground truth: the matching reference frames of every query
    frame; when given, it decides what is correct instead of the radius. It is a :class:`Positives`, one list of
    reference indices per query, or a ``[N_query, N_reference]`` bool or 0/1 matrix, as an array or as its rows
    (``.tolist()``; 0/1 rows that fit both readings, at most two wide, are refused). A ``[N_reference, N_query]``
    matrix is refused with a hint when not square; a square one is read as given, and one that reads better
    transposed is said by the evaluation: :func:`seqnet.data.sanity.truth.transposed_positives`.
    """

    reference: Traverse
    query: Traverse
    radius: float
    position_unit: str | None = None  # None: "frames" for [N, 1] positions, "metres" for [N, 2]
    splits: dict[str, dict[str, tuple[int, int]]] = dataclasses.field(default_factory=dict)
    name: str = "dataset"
    extra: dict[str, Any] = dataclasses.field(default_factory=dict)
    positives: Positives | None = None
    # split(): the dataset it was taken from and the split's name (in memory only: what identifies its queries)
    source: tuple[Dataset, str] | None = dataclasses.field(default=None, repr=False, compare=False)
    # load_dataset(): the directory it was read from (in memory only; a split has none: its source has it)
    path: Path | None = dataclasses.field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        for side in ("reference", "query"):
            if not isinstance(getattr(self, side), Traverse):
                raise DatasetError(f"Dataset {side} must be a Traverse, got {type(getattr(self, side)).__name__}")
            if getattr(self, side).name == "traverse":  # built without a name: its messages name its side
                named = copy.copy(getattr(self, side))  # a shallow copy: the caller's traverse keeps its name,
                named.name = side  # and the checked arrays are shared, not checked again
                setattr(self, side, named)
        if isinstance(self.radius, (bool, str)) or not isinstance(self.radius, (int, float, np.number)):
            raise DatasetError(f"radius must be a number, got {self.radius!r}")
        self.radius = float(self.radius)
        if self.positives is not None:
            self.positives = as_positives(self.positives, len(self.query), len(self.reference))
        if self.position_unit is None:
            self.position_unit = "frames" if self.reference.positions.shape[1] == 1 else "metres"
        self.splits = {name: self._whole_reference(rng) for name, rng in self.splits.items()}
        validate_dataset(self)

    def __repr__(self) -> str:
        splits = ", ".join(f"{k}={v['query'][0]}:{v['query'][1]}" for k, v in self.splits.items()) or "none"
        truth = "explicit positives" if self.positives is not None else f"radius {self.radius:g} {self.position_unit}"
        return (f"Dataset({self.name!r}: {len(self.reference)} reference x {len(self.query)} query images, "
                f"D={self.reference.dim}, {truth}, splits {splits})")

    def _whole_reference(self, rng: dict[str, tuple[int, int]]) -> dict[str, tuple[int, int]]:
        """``rng`` with the whole reference when it gives only a query range (a split selects queries)."""
        return {"reference": tuple(rng.get("reference", (0, len(self.reference)))),
                **{k: tuple(v) for k, v in rng.items() if k != "reference"}}

    def ranges(self, split: str | None) -> dict[str, tuple[int, int]] | None:
        """``{"reference": (a, b), "query": (c, d)}`` of a named split, of a range spec (:func:`parse_range_spec`)
        or of ``all`` / None (the whole traverses); None for anything else."""
        if split in (None, "all"):
            return {"reference": (0, len(self.reference)), "query": (0, len(self.query))}
        rng = self.splits.get(split) or parse_range_spec(split)
        return None if rng is None else self._whole_reference(rng)

    def split(self, split: str | None) -> Dataset:
        """The dataset restricted to a named split (None or "all": the whole dataset), or to a range given
        in place of a name: ``"A:B"`` (queries A:B against the whole reference) or ``"A:B,C:D"`` (reference
        A:B, queries C:D), so re-splitting needs no new dataset and no describing again."""
        if split in (None, "all"):
            return self
        rng = self.ranges(split)
        if rng is None:
            valid = ", ".join(["all", *self.splits]) or "all"
            raise DatasetError(f"dataset {self.name!r} has no split {split!r}; valid: {valid}, or a range A:B "
                               "(queries) / A:B,C:D (reference, queries)")
        if split not in self.splits:
            check_split(split, rng, self)
        positives = None
        if self.positives is not None:
            positives = self.positives.select(np.arange(*rng["query"]), np.arange(*rng["reference"]))
        return dataclasses.replace(
            self,
            reference=self.reference.subset(*rng["reference"]),
            query=self.query.subset(*rng["query"]),
            splits={},
            name=f"{self.name}[{split}]",
            positives=positives,
            source=(self, split) if self.source is None else None,  # a split of a split: its numbering is lost
            path=None,
        )


def parse_range_spec(spec: str) -> dict[str, tuple[int, int]] | None:
    """``"A:B"`` → ``{"query": (A, B)}`` (queries against the whole reference); ``"A:B,C:D"`` → reference A:B,
    queries C:D; None when ``spec`` is neither."""
    try:
        parts = [tuple(int(x) for x in r.split(":")) for r in spec.split(",")]
    except ValueError:
        return None
    if len(parts) not in (1, 2) or any(len(r) != 2 for r in parts):
        return None
    return {"reference": parts[0], "query": parts[1]} if len(parts) == 2 else {"query": parts[0]}


def default_split(split: str | None, splits: Mapping[str, Any]) -> str:
    """``split``, else ``test`` when the dataset defines one, else ``all``."""
    return split or ("test" if "test" in splits else "all")


def validate_dataset(ds: Dataset) -> None:
    """Raise :class:`DatasetError` naming the first inconsistency of dataset ``ds``."""
    if ds.reference.dim != ds.query.dim:
        raise DatasetError(
            f"descriptor dimension mismatch: reference D={ds.reference.dim}, query D={ds.query.dim}"
        )
    if ds.reference.positions.shape[1] != ds.query.positions.shape[1]:
        raise DatasetError("reference and query positions differ in kind ([N, 1] frames vs [N, 2] UTM)")
    if not (np.isfinite(ds.radius) and ds.radius > 0):
        raise DatasetError(f"radius must be a positive number, got {ds.radius!r}")
    if ds.position_unit not in POSITION_UNITS:
        said = ds.position_unit
        raise DatasetError(f"position_unit {said!r} is not one of {POSITION_UNITS}{unit_hint(said)}")
    for split, rng in ds.splits.items():
        check_split(split, rng, ds)
    if ds.source is None:  # a split's traverses are its source's, checked when it was made
        check_orientation(ds)


def unit_hint(unit: object) -> str:
    """`` (hint: "metres" ...)`` for a ``position_unit`` spelt another way ("meters", "m", "frame"), else ""."""
    said = str(unit).strip().lower()
    if said in ("m", "meter", "meters", "metre", "metres", "utm"):
        return ' (hint: "metres": UTM easting/northing or any metric positions)'
    if said in ("frame", "frames", "index", "indices"):
        return ' (hint: "frames": frame numbers, the radius a number of frames)'
    return ""


def check_orientation(ds: Dataset) -> None:
    """Refuse ``ds`` when a square ``[N, N]`` descriptor array (whose shape cannot tell images from dimensions)
    reads decisively as ``[D, N]`` (:func:`seqnet.data.orientation.read_square`), unless the user said the rows are
    images (:func:`seqnet.data.orientation.overridden`: said in the environment, it is recorded in ``ds.extra``, so
    the dataset written keeps it); suggestive evidence is a warning of :mod:`seqnet.data.sanity`."""
    if ds.extra.get(OVERRIDE_KEY):
        return
    for side, t in (("reference", ds.reference), ("query", ds.query)):
        o = read_square(t.descriptors)
        if o.verdict != "transposed" or not o.strong:
            continue
        if overridden():
            ds.extra[OVERRIDE_KEY] = True
            logger.warning("%s: the %s descriptors read as transposed (%s); kept as given (%s)", ds.name, side,
                           o.why, OVERRIDE_ENV)
            return
        n = len(t)
        raise DatasetError(f"{ds.name}: the {side} descriptors [{n}, {n}] look transposed (their columns look like "
                           f"the images: {o.why}); seqnet expects [N, D], one row per image; {orientation_hint(side)}")


def check_split(split: str, rng: dict[str, tuple[int, int]], ds: Dataset) -> None:
    """Both ranges of ``split`` are non-empty and inside their traverses (:class:`DatasetError` otherwise)."""
    for side, t in (("reference", ds.reference), ("query", ds.query)):
        if side not in rng:
            raise DatasetError(f"split {split!r} has no {side} range")
        a, b = rng[side]
        if not (0 <= a < b <= len(t)):
            raise DatasetError(f"split {split!r}: {side} range {a}:{b} is outside 0:{len(t)} or empty")
