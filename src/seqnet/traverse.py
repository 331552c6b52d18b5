"""Data model: traverses and datasets, and the seqnet dataset directory format.

A *traverse* is one pass along a route: single-image descriptors ``[N, D]``, positions ``[N, 1]``
(frame numbers) or ``[N, 2]`` (UTM easting/northing, metres), optional image names and optional
sequence bounds ``[N, 2]`` (for each image, the half-open frame range ``[start, end)`` of the
sequence it belongs to). A *dataset* pairs a reference and a query traverse with a localisation
radius and optional train/val/test index ranges.

Directory format (see docs/dataset_format.md)::

    DIR/dataset.json            {"format": "seqnet-dataset/1", "radius": 1.0, ...}
    DIR/reference/descriptors.npy | descriptors.h5   [N, D] float32 (h5: dataset "descriptors")
    DIR/reference/positions.npy | positions.csv      [N, 1] or [N, 2]
    DIR/reference/names.txt                          optional, one image name per line
    DIR/reference/seq_bounds.npy                     optional, [N, 2] int
    DIR/query/...                                    same layout
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import tempfile
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from .errors import DatasetError
from .utils import current_umask, logger, save_npy_atomic, write_json_atomic

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
    """

    descriptors: np.ndarray
    positions: np.ndarray
    names: list[str] | None = None
    seq_bounds: np.ndarray | None = None
    name: str = "traverse"

    def __post_init__(self) -> None:
        if not isinstance(self.descriptors, np.ndarray):
            try:
                self.descriptors = np.asarray(self.descriptors)
            except (TypeError, ValueError) as e:
                raise DatasetError(f"{self.name}: descriptors are not an [N, D] array ({e})") from None
        try:
            self.positions = np.asarray(self.positions, dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise DatasetError(f"{self.name}: positions must be numbers ({e})") from None
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
        return Traverse(
            descriptors=self.descriptors[start:stop],
            positions=self.positions[start:stop],
            names=None if self.names is None else self.names[start:stop],
            seq_bounds=bounds,
            name=self.name,
        )

    def with_descriptors(self, descriptors: np.ndarray) -> Traverse:
        """Same traverse (positions, names, bounds) with other descriptors ``[N, D']``."""
        return dataclasses.replace(self, descriptors=descriptors)


@dataclasses.dataclass
class Dataset:
    """A reference traverse, a query traverse and a localisation radius.

    ``splits`` maps a split name to ``{"reference": (start, stop), "query": (start, stop)}``.
    ``extra`` holds any other metadata (positive/negative training radii, preset, source, ...).
    """

    reference: Traverse
    query: Traverse
    radius: float
    position_unit: str | None = None  # None: "frames" for [N, 1] positions, "metres" for [N, 2]
    splits: dict[str, dict[str, tuple[int, int]]] = dataclasses.field(default_factory=dict)
    name: str = "dataset"
    extra: dict[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.position_unit is None:
            self.position_unit = "frames" if self.reference.positions.shape[1] == 1 else "metres"
        validate_dataset(self)

    def split(self, split: str | None) -> Dataset:
        """The dataset restricted to a named split (None or "all": the whole dataset)."""
        if split in (None, "all"):
            return self
        if split not in self.splits:
            valid = ", ".join(["all", *self.splits]) or "all"
            raise DatasetError(f"dataset {self.name!r} has no split {split!r}; valid: {valid}")
        rng = self.splits[split]
        return dataclasses.replace(
            self,
            reference=self.reference.subset(*rng["reference"]),
            query=self.query.subset(*rng["query"]),
            splits={},
            name=f"{self.name}[{split}]",
        )


def validate_traverse(t: Traverse) -> None:
    """Raise :class:`DatasetError` naming the first problem of traverse ``t``."""
    d = t.descriptors
    if d.ndim != 2:
        raise DatasetError(f"{t.name}: descriptors must be [N, D], got shape {tuple(d.shape)}")
    if d.shape[0] == 0 or d.shape[1] == 0:
        raise DatasetError(f"{t.name}: descriptors are empty (shape {tuple(d.shape)})")
    if not np.issubdtype(d.dtype, np.floating):
        raise DatasetError(f"{t.name}: descriptors must be floating point, got dtype {d.dtype}")
    _check_finite(d, f"{t.name}: descriptors")
    n = d.shape[0]
    p = t.positions
    if p.ndim != 2 or p.shape[1] not in (1, 2):
        raise DatasetError(
            f"{t.name}: positions must be [N, 1] (frames) or [N, 2] (easting, northing), "
            f"got shape {tuple(p.shape)}"
        )
    if p.shape[0] != n:
        raise DatasetError(f"{t.name}: {p.shape[0]} positions for {n} descriptors (must be equal)")
    _check_finite(p, f"{t.name}: positions")
    if t.names is not None and len(t.names) != n:
        raise DatasetError(f"{t.name}: {len(t.names)} image names for {n} descriptors")
    if t.seq_bounds is not None:
        _check_bounds(t.seq_bounds, n, t.name)


def _check_bounds(b: np.ndarray, n: int, name: str) -> None:
    if b.shape != (n, 2):
        raise DatasetError(f"{name}: seq_bounds must be [{n}, 2], got shape {tuple(b.shape)}")
    idx = np.arange(n)
    bad = np.flatnonzero((b[:, 0] < 0) | (b[:, 0] > idx) | (b[:, 1] <= idx) | (b[:, 1] > n))
    if bad.size:
        i = int(bad[0])
        raise DatasetError(
            f"{name}: seq_bounds[{i}] = {b[i].tolist()} does not contain image {i} within 0:{n} "
            f"({bad.size} bad rows; each row is the half-open range [start, end) of the image's sequence)"
        )


def _check_finite(a: np.ndarray, what: str, chunk: int = 65536) -> None:
    for s in range(0, a.shape[0], chunk):
        block = np.asarray(a[s : s + chunk])
        if not np.isfinite(block).all():
            row = s + int(np.flatnonzero(~np.isfinite(block).all(axis=1))[0])
            raise DatasetError(f"{what} contain NaN or inf (first at row {row})")


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
        raise DatasetError(f"position_unit {ds.position_unit!r} is not one of {POSITION_UNITS}")
    for split, rng in ds.splits.items():
        for side, t in (("reference", ds.reference), ("query", ds.query)):
            if side not in rng:
                raise DatasetError(f"split {split!r} has no {side} range")
            a, b = rng[side]
            if not (0 <= a < b <= len(t)):
                raise DatasetError(f"split {split!r}: {side} range {a}:{b} is outside 0:{len(t)} or empty")


# ----------------------------------------------------------------------------- reading


def load_dataset(path: str | Path, mmap: bool = True) -> Dataset:
    """Load and validate a dataset directory; raise :class:`DatasetError` saying what is wrong."""
    root = Path(path)
    if not root.exists():
        raise DatasetError(f"dataset directory not found: {root}")
    if not root.is_dir():
        raise DatasetError(f"dataset path is not a directory: {root}")
    meta_path = root / "dataset.json"
    if not meta_path.is_file():
        raise DatasetError(f"{root} is not a seqnet dataset: dataset.json is missing "
                           "(hint: `seqnet synth DIR` writes an example)")
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise DatasetError(f"{meta_path}: not valid JSON ({e})") from None
    if not isinstance(meta, dict):
        raise DatasetError(f"{meta_path}: must hold a JSON object")
    if "radius" not in meta:
        raise DatasetError(f"{meta_path}: missing key 'radius' (localisation radius, metres or frames)")
    try:
        radius = float(meta["radius"])
    except (TypeError, ValueError):
        raise DatasetError(f"{meta_path}: radius must be a number, got {meta['radius']!r}") from None
    trav = meta.get("traverses", {"reference": "reference", "query": "query"})
    if not isinstance(trav, dict) or not all(isinstance(v, str) for v in trav.values()):
        raise DatasetError(f"{meta_path}: 'traverses' must be an object like "
                           '{"reference": "ref", "query": "qry"}')
    ref = load_traverse(root / trav.get("reference", "reference"), "reference", mmap)
    qry = load_traverse(root / trav.get("query", "query"), "query", mmap)
    return Dataset(
        reference=ref,
        query=qry,
        radius=radius,
        position_unit=meta.get("position_unit"),
        splits=_parse_splits(meta.get("splits", {}), meta_path),
        name=str(meta.get("name", root.name)),
        extra={k: v for k, v in meta.items() if k not in _META_KEYS},
    )


_META_KEYS = {"format", "radius", "position_unit", "splits", "name", "traverses"}


def _parse_splits(raw: Any, where: Path) -> dict[str, dict[str, tuple[int, int]]]:
    if not isinstance(raw, dict):
        raise DatasetError(f"{where}: 'splits' must be an object like {{\"test\": [0, 100]}}")
    out: dict[str, dict[str, tuple[int, int]]] = {}
    for name, rng in raw.items():
        try:
            if isinstance(rng, dict):
                out[name] = {k: (int(rng[k][0]), int(rng[k][1])) for k in ("reference", "query")}
            else:
                a, b = int(rng[0]), int(rng[1])
                out[name] = {"reference": (a, b), "query": (a, b)}
        except (KeyError, TypeError, ValueError, IndexError):
            raise DatasetError(
                f"{where}: split {name!r} must be [start, stop] or "
                "{\"reference\": [start, stop], \"query\": [start, stop]}"
            ) from None
    return out


def load_traverse(path: Path, name: str, mmap: bool = True) -> Traverse:
    """Load one traverse directory (descriptors, positions, optional names and seq_bounds)."""
    if not path.is_dir():
        raise DatasetError(f"{name} traverse directory not found: {path}")
    desc, h5_names = load_descriptors(path, mmap)
    pos = _load_positions(path)
    names = h5_names
    if (path / "names.txt").is_file():
        try:
            names = (path / "names.txt").read_text(encoding="utf-8").splitlines()
        except UnicodeDecodeError as e:
            raise DatasetError(f"{path / 'names.txt'}: not UTF-8 text ({e.reason} at byte {e.start})") from None
    bounds = None
    if (path / "seq_bounds.npy").is_file():
        bounds = _load_npy(path / "seq_bounds.npy", mmap=False)
        if not np.issubdtype(bounds.dtype, np.integer):
            raise DatasetError(f"{path / 'seq_bounds.npy'}: must hold integers, got {bounds.dtype}")
    return Traverse(descriptors=desc, positions=pos, names=names, seq_bounds=bounds, name=f"{name} ({path})")


def load_descriptors(path: Path, mmap: bool = True) -> tuple[np.ndarray, list[str] | None]:
    """Load ``descriptors.npy`` (memory-mapped) or ``descriptors.h5`` from a traverse directory."""
    for fname in DESCRIPTOR_FILES:
        f = path / fname
        if f.is_file():
            if f.suffix == ".npy":
                return _load_npy(f, mmap), None
            return _load_h5(f)
    raise DatasetError(f"no descriptor file in {path}; expected one of {', '.join(DESCRIPTOR_FILES)}")


def _load_npy(f: Path, mmap: bool) -> np.ndarray:
    with open(f, "rb") as fh:
        magic = fh.read(6)
    if magic != b"\x93NUMPY":
        what = "not in .npy format (no NumPy header)"
        if not magic:
            what = "empty"
        elif magic.startswith(b"PK"):
            what = "a .npz archive"
        raise DatasetError(f"cannot read {f} as a .npy array: the file is {what}")
    try:
        arr = np.load(f, mmap_mode="r" if mmap else None, allow_pickle=False)
    except (ValueError, OSError, EOFError) as e:
        msg = "it holds Python objects (pickled data), not numbers" if "pickle" in str(e) else str(e)
        raise DatasetError(f"cannot read {f} as a .npy array ({msg})") from None
    if not isinstance(arr, np.ndarray):  # pragma: no cover - np.load only returns arrays after the magic check
        raise DatasetError(f"cannot read {f} as a .npy array")
    return arr


def _load_h5(f: Path) -> tuple[np.ndarray, list[str] | None]:
    import h5py

    try:
        with h5py.File(f, "r") as h:
            if not isinstance(h.get("descriptors"), h5py.Dataset):
                raise DatasetError(f"{f}: HDF5 file has no dataset 'descriptors' (found: {list(h.keys())})")
            desc = np.asarray(h["descriptors"][()])
            names = None
            if isinstance(h.get("names"), h5py.Dataset):
                names = [n.decode() if isinstance(n, bytes) else str(n) for n in np.atleast_1d(h["names"][()])]
    except (OSError, TypeError, ValueError, UnicodeDecodeError) as e:
        raise DatasetError(f"cannot read {f} as HDF5 ({e})") from None
    return desc, names


def _load_positions(path: Path) -> np.ndarray:
    for fname in POSITION_FILES:
        f = path / fname
        if f.is_file():
            if f.suffix == ".npy":
                return _load_npy(f, mmap=False)
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # an empty file is reported below, not warned about
                    arr = np.loadtxt(f, delimiter="," if f.suffix == ".csv" else None, ndmin=2)
            except (ValueError, UnicodeDecodeError) as e:
                raise DatasetError(f"cannot parse {f} as numbers ({' '.join(str(e).split())})") from None
            if arr.size == 0:
                raise DatasetError(f"{f} holds no positions (the file is empty)")
            return arr
    raise DatasetError(f"no positions file in {path}; expected one of {', '.join(POSITION_FILES)}")


# ----------------------------------------------------------------------------- writing


def save_dataset(ds: Dataset, path: str | Path, overwrite: bool = False) -> Path:
    """Write ``ds`` in the directory format; never leaves a half-written dataset behind.

    Everything is written into a temporary sibling directory which is then renamed onto ``path``.
    With ``overwrite``, an existing ``path`` is first renamed aside and deleted only after the new
    directory is in place (restored if that rename fails).
    """
    root = Path(path)
    if root.exists() and not root.is_dir():
        raise DatasetError(f"output path {root} exists and is not a directory")
    if root.exists() and any(root.iterdir()) and not overwrite:
        raise DatasetError(f"output directory {root} exists and is not empty (use --overwrite to replace it)")
    root.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=root.parent, prefix=f".{root.name}.", suffix=".tmp"))
    old: Path | None = None
    try:
        tmp.chmod(0o777 & ~current_umask())  # mkdtemp makes it 0700; a plain mkdir would not
        for side, t in (("reference", ds.reference), ("query", ds.query)):
            save_traverse(t, tmp / side)
        meta = {
            **{k: v for k, v in ds.extra.items() if k not in _META_KEYS},
            "format": FORMAT,
            "name": ds.name,
            "radius": ds.radius,
            "position_unit": ds.position_unit,
            "splits": {k: {s: list(v[s]) for s in ("reference", "query")} for k, v in ds.splits.items()},
        }
        write_json_atomic(tmp / "dataset.json", meta)
        if root.exists():
            old = Path(tempfile.mkdtemp(dir=root.parent, prefix=f".{root.name}.", suffix=".old"))
            old.rmdir()
            root.rename(old)
        try:
            tmp.rename(root)
        except OSError:
            if old is not None:
                old.rename(root)
                old = None
            raise
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
        if old is not None and old.exists():
            shutil.rmtree(old, ignore_errors=True)
    logger.info("wrote dataset %s (reference %d, query %d images)", root, len(ds.reference), len(ds.query))
    return root


def save_traverse(t: Traverse, path: Path) -> None:
    """Write one traverse directory (descriptors.npy, positions.npy, names.txt, seq_bounds.npy)."""
    path.mkdir(parents=True, exist_ok=True)
    save_npy_atomic(path / "descriptors.npy", np.ascontiguousarray(t.descriptors, dtype=np.float32))
    save_npy_atomic(path / "positions.npy", t.positions)
    if t.names is not None:
        bad = next((n for n in t.names if "\n" in n or "\r" in n), None)
        if bad is not None:
            raise DatasetError(f"{t.name}: image name {bad!r} contains a line break (names.txt: one name a line)")
        (path / "names.txt").write_text("\n".join(t.names) + "\n", encoding="utf-8")
    if t.seq_bounds is not None:
        save_npy_atomic(path / "seq_bounds.npy", t.seq_bounds)
