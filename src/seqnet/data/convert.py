"""Build datasets from CSV files, descriptor files and UTM-coded image names.

Inputs, per traverse (reference and query):

* a descriptor file ``[N, D]``: ``.npy`` (image names from a names file, one per line) or HDF5
  (``.h5`` / ``.hdf5``: dataset ``descriptors`` — or the only 2-D dataset — and optional ``names``);
* positions, either from a CSV file (a header row naming an image column and ``easting, northing``
  in metres, or ``frame``; rows are matched to the descriptors by image name, and an optional
  ``sequence`` column gives sequence bounds), or from the image names themselves when they carry
  UTM coordinates as ``@<easting>@<northing>@...`` (Pittsburgh, Tokyo 24/7, MSLS-style names).

Everything here is a pure function of its inputs returning arrays or :class:`Traverse` objects.
"""

from __future__ import annotations

import csv
import re
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DatasetError
from .traverse import Dataset, Traverse

NAME_COLUMNS = ("name", "image", "image_name", "filename", "file", "path", "key", "image_key")
EAST_COLUMNS = ("easting", "east", "utm_east", "utm_easting", "x")
NORTH_COLUMNS = ("northing", "north", "utm_north", "utm_northing", "y")
FRAME_COLUMNS = ("frame", "frame_number", "frame_id", "frame_index")
SEQUENCE_COLUMNS = ("sequence", "sequence_key", "seq", "seq_key")
UTM_NAME = re.compile(r"@([-+]?\d+(?:\.\d*)?)@([-+]?\d+(?:\.\d*)?)@")


def read_names(path: str | Path) -> list[str]:
    """Image names, one per non-blank line of a text file."""
    p = Path(path)
    if not p.is_file():
        raise DatasetError(f"names file not found: {p}")
    return [line.strip() for line in p.read_text(encoding="utf-8").splitlines() if line.strip()]


def read_descriptor_file(path: str | Path, names_file: str | Path | None = None) -> tuple[np.ndarray, list[str] | None]:
    """Descriptors ``[N, D]`` and their image names (from HDF5 ``names`` or ``names_file``; else None)."""
    p = Path(path)
    if not p.is_file():
        raise DatasetError(f"descriptor file not found: {p}")
    if p.suffix.lower() == ".npy":
        try:
            desc = np.load(p, mmap_mode="r", allow_pickle=False)
        except (ValueError, OSError, EOFError) as e:
            raise DatasetError(f"cannot read {p} as a .npy array ({e})") from None
        names = None
    elif p.suffix.lower() in (".h5", ".hdf5"):
        desc, names = _read_h5(p)
    else:
        raise DatasetError(f"descriptor file {p} must be .npy, .h5 or .hdf5 (got {p.suffix or 'no extension'!r})")
    if desc.ndim != 2:
        raise DatasetError(f"{p}: descriptors must be [N, D], got shape {tuple(desc.shape)}")
    if names_file is not None:
        names = read_names(names_file)
    if names is not None and len(names) != desc.shape[0]:
        src = names_file or f"{p}:names"
        raise DatasetError(f"{src}: {len(names)} names for {desc.shape[0]} descriptors in {p} (must be equal)")
    return desc, names


def _read_h5(p: Path) -> tuple[np.ndarray, list[str] | None]:
    import h5py

    try:
        with h5py.File(p, "r") as h:
            key = "descriptors" if "descriptors" in h else None
            if key is None:
                two_d = [k for k, v in h.items() if isinstance(v, h5py.Dataset) and v.ndim == 2 and k != "names"]
                if len(two_d) != 1:
                    raise DatasetError(f"{p}: no dataset 'descriptors' and {len(two_d)} other 2-D datasets "
                                       f"(found: {list(h.keys())}); hint: name the descriptor dataset 'descriptors'")
                key = two_d[0]
            desc = np.asarray(h[key][()])
            names = [n.decode() if isinstance(n, bytes) else str(n) for n in h["names"][()]] if "names" in h else None
    except OSError as e:
        raise DatasetError(f"cannot read {p} as HDF5 ({e})") from None
    return desc, names


def match_names(wanted: list[str], available: list[str], what: str) -> np.ndarray:
    """Index into ``available`` of each name in ``wanted``, ``[len(wanted)]`` int64.

    Names match exactly, else by file name (last path component), else by file name without
    extension. Raises :class:`DatasetError` naming the first name that does not match.
    """
    for key in (lambda s: s, lambda s: s.replace("\\", "/").rsplit("/", 1)[-1],
                lambda s: s.replace("\\", "/").rsplit("/", 1)[-1].rsplit(".", 1)[0]):
        table: dict[str, int] = {}
        for i, n in enumerate(available):
            table.setdefault(key(n), i)
        idx = [table.get(key(n), -1) for n in wanted]
        if min(idx, default=0) >= 0:
            return np.asarray(idx, dtype=np.int64)
    missing = [n for n, i in zip(wanted, idx, strict=True) if i < 0]
    raise DatasetError(f"{what}: {len(missing)} of {len(wanted)} image names have no descriptor "
                       f"(first: {missing[0]!r}; descriptor names look like {available[0]!r}); "
                       "hint: names are matched exactly, then by file name, then without extension")


def parse_utm_name(name: str) -> tuple[float, float]:
    """``(easting, northing)`` from a name like ``@0543256.96@4477929.94@17@T@...jpg``."""
    m = UTM_NAME.search(name.replace("\\", "/").rsplit("/", 1)[-1])
    if m is None:
        raise DatasetError(f"image name {name!r} carries no UTM coordinates; expected '@<easting>@<northing>@...' "
                           "(e.g. '@0543256.96@4477929.94@17@T@...jpg')")
    return float(m.group(1)), float(m.group(2))


def utm_positions(names: list[str]) -> np.ndarray:
    """``[N, 2]`` easting/northing parsed from UTM-coded image names."""
    return np.array([parse_utm_name(n) for n in names], dtype=np.float64).reshape(-1, 2)


def read_positions_csv(path: str | Path) -> tuple[list[str], np.ndarray, str, np.ndarray | None]:
    """Read a positions CSV: ``(names, positions [N, P], unit, seq_bounds [N, 2] or None)``.

    The header names an image column (one of :data:`NAME_COLUMNS`) and either easting/northing
    columns (metres) or a frame column (frames); an optional sequence column gives, for each row,
    the half-open range of the run of consecutive rows with the same sequence key.
    """
    p = Path(path)
    if not p.is_file():
        raise DatasetError(f"positions CSV not found: {p}")
    with p.open(newline="", encoding="utf-8") as f:
        rows = [r for r in csv.reader(f) if r and any(c.strip() for c in r)]
    if len(rows) < 2:
        raise DatasetError(f"{p}: needs a header row and at least one data row")
    header = [h.strip().lower() for h in rows[0]]
    col = _find_columns(header, p)
    names = [r[col["name"]].strip() for r in rows[1:]]
    pos_cols = [col["east"], col["north"]] if "east" in col else [col["frame"]]
    try:
        pos = np.array([[float(r[c]) for c in pos_cols] for r in rows[1:]], dtype=np.float64)
    except (ValueError, IndexError):
        bad = next(i for i, r in enumerate(rows[1:], start=2) if not _numeric(r, pos_cols))
        cols = [header[c] for c in pos_cols]
        raise DatasetError(f"{p}, line {bad}: position columns {cols} must be numbers") from None
    bounds = runs_to_bounds([r[col["seq"]] for r in rows[1:]]) if "seq" in col else None
    return names, pos, ("metres" if "east" in col else "frames"), bounds


def _numeric(row: list[str], cols: list[int]) -> bool:
    try:
        [float(row[c]) for c in cols]
    except (ValueError, IndexError):
        return False
    return True


def _find_columns(header: list[str], p: Path) -> dict[str, int]:
    def first(options: tuple[str, ...]) -> int | None:
        return next((header.index(o) for o in options if o in header), None)

    col = {k: i for k, i in (("name", first(NAME_COLUMNS)), ("east", first(EAST_COLUMNS)),
                             ("north", first(NORTH_COLUMNS)), ("frame", first(FRAME_COLUMNS)),
                             ("seq", first(SEQUENCE_COLUMNS))) if i is not None}
    if "name" not in col:
        raise DatasetError(f"{p}: header {header} has no image-name column; valid: {', '.join(NAME_COLUMNS)}")
    if ("east" in col) != ("north" in col) or ("east" not in col and "frame" not in col):
        raise DatasetError(f"{p}: header {header} needs easting and northing columns ({'/'.join(EAST_COLUMNS)}, "
                           f"{'/'.join(NORTH_COLUMNS)}) or a frame column ({'/'.join(FRAME_COLUMNS)})")
    if "east" in col:
        col.pop("frame", None)
    return col


def runs_to_bounds(keys: list[str]) -> np.ndarray:
    """``[N, 2]`` half-open range of the run of equal consecutive keys each row belongs to."""
    n = len(keys)
    starts = [0] + [i for i in range(1, n) if keys[i] != keys[i - 1]]
    ends = starts[1:] + [n]
    out = np.empty((n, 2), dtype=np.int64)
    for a, b in zip(starts, ends, strict=True):
        out[a:b] = (a, b)
    return out


def read_seq_bounds(path: str | Path, n: int | None = None) -> np.ndarray:
    """Sequence bounds file (one ``start end`` row per image, half-open) as ``[N, 2]`` int64."""
    p = Path(path)
    if not p.is_file():
        raise DatasetError(f"sequence bounds file not found: {p}")
    try:
        b = np.loadtxt(p, dtype=np.int64, ndmin=2)
    except ValueError as e:
        raise DatasetError(f"{p}: expected one 'start end' row of integers per image ({e})") from None
    if b.shape[1] != 2:
        raise DatasetError(f"{p}: expected 2 columns (start end), got {b.shape[1]}")
    if n is not None and len(b) != n:
        raise DatasetError(f"{p}: {len(b)} sequence-bound rows for {n} images (must be one row per image)")
    return b


def traverse_from_csv(csv_path: str | Path, desc_path: str | Path, names_file: str | Path | None = None,
                      name: str = "traverse") -> tuple[Traverse, str]:
    """A traverse from a positions CSV and a descriptor file matched by image name; also the unit.

    Without descriptor names, the CSV rows must be in descriptor order (same count).
    """
    names, pos, unit, bounds = read_positions_csv(csv_path)
    desc, desc_names = read_descriptor_file(desc_path, names_file)
    if desc_names is None:
        if len(names) != desc.shape[0]:
            raise DatasetError(f"{csv_path}: {len(names)} rows but {desc_path} holds {desc.shape[0]} descriptors and "
                               "no names; hint: give a names file (--*-names) or HDF5 'names' to match by name")
        idx = np.arange(len(names))
    else:
        idx = match_names(names, desc_names, f"{csv_path} vs {desc_path}")
    d = desc if np.array_equal(idx, np.arange(desc.shape[0])) else np.asarray(desc[idx])
    return Traverse(descriptors=_float(d), positions=pos, names=names, seq_bounds=bounds, name=name), unit


def traverse_from_utm_names(desc_path: str | Path, names_file: str | Path | None = None,
                            name: str = "traverse") -> Traverse:
    """A traverse whose positions are parsed from UTM-coded image names (HDF5 names or a names file)."""
    desc, names = read_descriptor_file(desc_path, names_file)
    if names is None:
        raise DatasetError(f"{desc_path}: no image names; give a names file or an HDF5 file with a 'names' dataset")
    return Traverse(descriptors=_float(desc), positions=utm_positions(names), names=names, name=name)


def _float(d: np.ndarray) -> np.ndarray:
    return d if np.issubdtype(d.dtype, np.floating) else np.asarray(d, dtype=np.float32)


def summarize_dataset(ds: Dataset) -> dict[str, Any]:
    """A JSON-ready summary of a dataset: sizes, dims, radius, true-match counts, sequence bounds.

    ``queries_with_match`` counts the query images with a reference within the radius (over the
    whole dataset and within each split).
    """
    from ..recall import has_positive

    def side(t: Traverse) -> dict[str, Any]:
        out: dict[str, Any] = {"images": len(t), "dim": t.dim}
        if t.seq_bounds is not None:
            lengths = np.diff(np.unique(t.seq_bounds, axis=0), axis=1).ravel()
            out["sequences"] = {"count": int(lengths.size), "min_len": int(lengths.min()),
                                "median_len": float(np.median(lengths)), "max_len": int(lengths.max())}
        return out

    def matches(q: Traverse, r: Traverse) -> int:
        return int(has_positive(q.positions, r.positions, ds.radius).sum())

    summary: dict[str, Any] = {
        "name": ds.name, "radius": ds.radius, "position_unit": ds.position_unit,
        "reference": side(ds.reference), "query": side(ds.query),
        "queries_with_match": matches(ds.query, ds.reference), "splits": {},
        "metadata": dict(ds.extra),
    }
    for split, rng in ds.splits.items():
        sub = ds.split(split)
        summary["splits"][split] = {"reference": list(rng["reference"]), "query": list(rng["query"]),
                                    "queries_with_match": matches(sub.query, sub.reference)}
    return summary


def assemble_dataset(
    ref: Traverse, query: Traverse, unit: str, radius: float | None = None, preset: str | None = None,
    splits: dict[str, dict[str, tuple[int, int]]] | None = None, name: str = "dataset",
    extra: dict[str, Any] | None = None,
) -> Dataset:
    """A dataset from two traverses; radius and training radii from ``radius`` / ``extra`` or ``preset``.

    Splits default to the preset's index splits when it defines them and they fit.
    """
    from ..errors import ConfigError
    from .presets import get_preset, preset_metadata, preset_splits

    meta: dict[str, Any] = {}
    if preset is not None:
        p = get_preset(preset)
        if p["position_unit"] != unit:
            raise ConfigError(f"preset {preset!r} expects positions in {p['position_unit']}, the data has {unit}")
        meta.update(preset_metadata(preset))
        radius = p["radius"] if radius is None else radius
        if splits is None and p.get("splits"):
            splits = preset_splits(preset, len(ref), len(query))
    if radius is None:
        raise ConfigError("no localisation radius: give --radius R (metres or frames) or --preset "
                          "(nordland, oxford-v1.0, oxford-pnv, brisbane, msls)")
    meta.update({k: v for k, v in (extra or {}).items() if v is not None})
    return Dataset(reference=ref, query=query, radius=float(radius), position_unit=unit, splits=splits or {},
                   name=name, extra=meta)
