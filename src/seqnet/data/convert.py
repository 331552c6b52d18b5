"""Build datasets from CSV files, descriptor files and UTM-coded image names.

Inputs, per traverse (reference and query):

* a descriptor file ``[N, D]``: ``.npy`` (image names from a names file, one per line) or HDF5
  (``.h5`` / ``.hdf5``: dataset ``descriptors`` and optional ``names``);
* positions, either from a CSV file (a header row naming an image column and ``easting, northing``
  in metres, ``lat, lon`` in degrees (unit ``degrees``: :func:`traverses_in_metres` makes both UTM metres), or
  ``frame``; rows are matched to the descriptors by image name, and an optional
  ``sequence`` column gives sequence bounds), or from the image names themselves when they carry
  UTM coordinates as ``@<easting>@<northing>@...`` (Pittsburgh, Tokyo 24/7, MSLS-style names).

Everything here is a pure function of its inputs returning arrays or :class:`Traverse` objects.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ConfigError, DatasetError
from ..core.log import logger
from ..core.provenance import check_same
from ..security.limits import POSITION_MAX
from .imagefolders import utm_positions
from .positives import Positives
from .readers import (
    check_names,
    read_descriptor_file,
    read_provenance,
    read_text,
    transposed_hint,
    warn_unless_unit_rows,
)
from .traverse import Dataset, Traverse
from .utm import check_latlon, latlon_pair

NAME_COLUMNS = ("name", "image", "image_name", "filename", "file", "path", "key", "image_key")
EAST_COLUMNS = ("easting", "east", "utm_east", "utm_easting", "x")
NORTH_COLUMNS = ("northing", "north", "utm_north", "utm_northing", "y")
LAT_COLUMNS = ("lat", "latitude")
LON_COLUMNS = ("lon", "lng", "longitude")
FRAME_COLUMNS = ("frame", "frame_number", "frame_id", "frame_index")
SEQUENCE_COLUMNS = ("sequence", "sequence_key", "seq", "seq_key")


def _basename(s: str) -> str:
    return s.replace("\\", "/").rsplit("/", 1)[-1]


NAME_KEYS = (lambda s: s, _basename, lambda s: _basename(s).rsplit(".", 1)[0])  # exact, file name, stem


def match_names(wanted: list[str], available: list[str], what: str) -> np.ndarray:
    """Index into ``available`` of each name in ``wanted``, ``[len(wanted)]`` int64.

    Names match exactly, else by file name (last path component), else by file name without
    extension. Raises :class:`DatasetError` naming the first name that does not match, or that
    matches two descriptors (ambiguous), instead of silently taking one of them.
    """
    idx: list[int] = []
    for key in NAME_KEYS:
        table: dict[str, list[int]] = {}
        for i, n in enumerate(available):
            table.setdefault(key(n), []).append(i)
        hits = [table.get(key(n), []) for n in wanted]
        if all(hits):
            bad = next((n for n, h in zip(wanted, hits, strict=True) if len(h) > 1), None)
            if bad is not None:
                first, second = table[key(bad)][:2]
                raise DatasetError(f"{what}: image name {bad!r} matches two descriptors ({available[first]!r} and "
                                   f"{available[second]!r}); hint: give names that identify one image each")
            idx = [h[0] for h in hits]
            return np.asarray(idx, dtype=np.int64)
    missing = [n for n, h in zip(wanted, hits, strict=True) if not h]
    looks = f"descriptor names look like {available[0]!r}" if available else "there are no descriptor names"
    raise DatasetError(f"{what}: {len(missing)} of {len(wanted)} image names have no descriptor "
                       f"(first: {missing[0]!r}; {looks}); "
                       "hint: names are matched exactly, then by file name, then without extension")


def read_csv_rows(path: str | Path) -> tuple[list[str], list[tuple[int, list[str]]]]:
    """The lower-cased header and the non-blank data rows ``(line number, fields)`` of a UTF-8 CSV file."""
    p = Path(path)
    if not p.exists():
        raise DatasetError(f"CSV file not found: {p}")
    text = read_text(p, "CSV file")  # a FIFO or device is refused, never read
    try:
        rows = [(n, r) for n, r in enumerate(csv.reader(io.StringIO(text, newline="")), start=1)]
    except csv.Error as e:
        raise DatasetError(f"{p}: not a valid CSV file ({' '.join(str(e).split())[:200]})") from e
    rows = [(n, r) for n, r in rows if r and any(c.strip() for c in r)]
    if len(rows) < 2:
        raise DatasetError(f"{p}: needs a header row and at least one data row")
    return [h.strip().lower() for h in rows[0][1]], rows[1:]


def read_positions_csv(path: str | Path) -> tuple[list[str], np.ndarray, str, np.ndarray | None]:
    """Read a positions CSV: ``(names, positions [N, P], unit, seq_bounds [N, 2] or None)``.

    The header names an image column (one of :data:`NAME_COLUMNS`) and either easting/northing
    columns (metres), lat/lon columns (unit ``degrees``: ``[N, 2]`` latitude, longitude, each checked
    in range; :func:`seqnet.data.utm.latlon_pair` makes them metres) or a frame column (frames); an
    optional sequence column gives, for each row,
    the half-open range of the run of consecutive rows with the same sequence key. A row with too
    few fields, a non-numeric position or a repeated image name is an error naming its line.
    """
    p = Path(path)
    header, rows = read_csv_rows(p)
    col = _find_columns(header, p)
    for line, r in rows:
        if len(r) <= max(col.values()):
            raise DatasetError(f"{p}, line {line}: {len(r)} fields, but the header has {len(header)} "
                               f"(columns {header})")
    names = [r[col["name"]].strip() for _, r in rows]
    first_line: dict[str, int] = {}
    for (line, _), name in zip(rows, names, strict=True):
        if name in first_line:
            raise DatasetError(f"{p}: image name {name!r} appears on lines {first_line[name]} and {line}; each image "
                               "must have one position (hint: remove the duplicate row)")
        first_line[name] = line
    check_names(names, f"{p} (column {header[col['name']]!r})")
    unit = "metres" if "east" in col else "degrees" if "lat" in col else "frames"
    pos_cols = {"metres": ["east", "north"], "degrees": ["lat", "lon"], "frames": ["frame"]}[unit]
    pos_cols = [col[c] for c in pos_cols]
    pos = np.empty((len(rows), len(pos_cols)), dtype=np.float64)
    for i, (line, r) in enumerate(rows):
        try:
            pos[i] = [float(r[c]) for c in pos_cols]
        except ValueError:
            pos[i] = np.nan
        if not (np.abs(pos[i]) <= POSITION_MAX).all():  # NaN too
            raise DatasetError(f"{p}, line {line}: position columns {[header[c] for c in pos_cols]} must be finite "
                               f"numbers within ±{POSITION_MAX:g}, got {[r[c][:40] for c in pos_cols]}")
    if unit == "degrees":
        check_latlon(pos, str(p), [line for line, _ in rows])
    bounds = runs_to_bounds([r[col["seq"]] for _, r in rows]) if "seq" in col else None
    return names, pos, unit, bounds


def _find_columns(header: list[str], p: Path) -> dict[str, int]:
    def first(options: tuple[str, ...]) -> int | None:
        return next((header.index(o) for o in options if o in header), None)

    col = {k: i for k, i in (("name", first(NAME_COLUMNS)), ("east", first(EAST_COLUMNS)),
                             ("north", first(NORTH_COLUMNS)), ("frame", first(FRAME_COLUMNS)),
                             ("lat", first(LAT_COLUMNS)), ("lon", first(LON_COLUMNS)),
                             ("seq", first(SEQUENCE_COLUMNS))) if i is not None}
    if "name" not in col:
        raise DatasetError(f"{p}: header {header} has no image-name column; valid: {', '.join(NAME_COLUMNS)}")
    pairs = [("east" in col, "north" in col), ("lat" in col, "lon" in col)]
    if any(a != b for a, b in pairs) or not (any(a for a, _ in pairs) or "frame" in col):
        raise DatasetError(f"{p}: header {header} needs easting and northing columns ({'/'.join(EAST_COLUMNS)}, "
                           f"{'/'.join(NORTH_COLUMNS)}), lat and lon columns ({'/'.join(LAT_COLUMNS)}, "
                           f"{'/'.join(LON_COLUMNS)}; degrees) or a frame column ({'/'.join(FRAME_COLUMNS)})")
    drop = ("frame", "lat", "lon") if "east" in col else ("frame",) if "lat" in col else ()
    return {k: i for k, i in col.items() if k not in drop}


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
    if not p.exists():
        raise DatasetError(f"sequence bounds file not found: {p}")
    rows = [ln for ln in read_text(p, "sequence bounds file").splitlines() if ln.split("#")[0].strip()]
    if not rows:  # (loadtxt would warn, then return nothing)
        raise DatasetError(f"{p}: holds no sequence bounds (the file is empty)")
    try:
        b = np.loadtxt(rows, dtype=np.int64, ndmin=2)
    except (ValueError, OverflowError) as e:
        raise DatasetError(f"{p}: expected one 'start end' row of integers per image ({str(e)[:160]})") from e
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
            raise DatasetError(f"{csv_path}: {len(names)} rows but {desc_path} holds {desc.shape[0]} descriptors"
                               + (transposed_hint(len(names), desc) or " and no names; hint: give a names file "
                                  "(--*-names) or HDF5 'names' to match by name"))
        idx = np.arange(len(names))
        logger.debug("%s: its rows are paired with the descriptors of %s by order (row i is descriptor i), not by "
                    "its image names: the rows must be in the descriptors' order; hint: a names file (--%s-names) "
                    "or HDF5 'names' pairs them by name", csv_path, desc_path, "ref" if name == "reference" else name)
    else:
        idx = match_names(names, desc_names, f"{csv_path} vs {desc_path}")
    d = desc if np.array_equal(idx, np.arange(desc.shape[0])) else np.asarray(desc[idx])
    return Traverse(descriptors=d, positions=pos, names=names, seq_bounds=bounds, name=name,
                    provenance=read_provenance(desc_path)), unit


def traverses_in_metres(ref: Traverse, qry: Traverse, files: tuple[str, str]) -> tuple[Traverse, Traverse, str]:
    """Both traverses with their lat/lon positions (unit ``degrees``, read from ``files``) as UTM metres, the
    query in the reference's zone (:func:`seqnet.data.utm.latlon_pair`); and that positions frame."""
    import dataclasses

    r, q, frame = latlon_pair(ref.positions, qry.positions, (str(files[0]), str(files[1])))
    return dataclasses.replace(ref, positions=r), dataclasses.replace(qry, positions=q), frame


def traverse_from_utm_names(desc_path: str | Path, names_file: str | Path | None = None,
                            name: str = "traverse") -> Traverse:
    """A traverse whose positions are parsed from UTM-coded image names (HDF5 names or a names file)."""
    desc, names = read_descriptor_file(desc_path, names_file)
    if names is None:
        raise DatasetError(f"{desc_path}: no image names; give a names file or an HDF5 file with a 'names' dataset")
    warn_unless_unit_rows(desc, desc_path)
    return Traverse(descriptors=desc, positions=utm_positions(names), names=names, name=name,
                    provenance=read_provenance(desc_path))


def positives_radius(positives: Positives, ref_positions: np.ndarray) -> float:
    """A radius implied by explicit positives: half the median distance spanned by one query's positives
    (at least the median step between consecutive reference frames, so a query with one positive counts)."""
    pos = np.asarray(ref_positions, dtype=np.float64)
    step = float(np.median(np.linalg.norm(np.diff(pos, axis=0), axis=1))) if len(pos) > 1 else 1.0
    spans = [np.linalg.norm(pos[idx].max(0) - pos[idx].min(0)) / 2
             for idx in (positives.indices[a:b] for a, b in zip(positives.indptr[:-1], positives.indptr[1:],
                                                                  strict=True)) if len(idx)]
    return max(float(np.median(spans)) if spans else 0.0, step, 1e-9)


def assemble_dataset(
    ref: Traverse, query: Traverse, unit: str, radius: float | None = None, preset: str | None = None,
    splits: dict[str, dict[str, tuple[int, int]]] | None = None, name: str = "dataset",
    extra: dict[str, Any] | None = None, positives: Positives | None = None, allow_mismatch: bool = False,
) -> Dataset:
    """A dataset from two traverses; radius and training radii from ``radius`` / ``extra`` or ``preset``.

    Splits default to the preset's index splits when it defines them and they fit. Reference and
    query descriptors made differently (provenance) are refused unless ``allow_mismatch``.
    """
    check_same(ref.provenance, query.provenance, "the reference descriptors", "the query descriptors",
               allow_mismatch)
    mismatched = bool(ref.provenance and query.provenance and ref.provenance.get("id") != query.provenance.get("id"))
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
    if radius is None and positives is not None:  # the radius only says "the same place" for the confidence
        radius = positives_radius(positives.check(len(query), len(ref)), ref.positions)
        logger.info("explicit positives and no --radius: radius %g (half the median span of a query's positives)",
                    radius)
    if radius is None:
        raise ConfigError("no localisation radius: give --radius R (metres or frames) or --preset "
                          "(nordland, oxford-v1.0, oxford-pnv, brisbane, msls)")
    meta.update({k: v for k, v in (extra or {}).items() if v is not None})
    if mismatched:  # accepted with --allow-mismatch: remembered, so later commands need not repeat it
        meta["allow_mismatch"] = True
    return Dataset(reference=ref, query=query, radius=float(radius), position_unit=unit, splits=splits or {},
                   name=name, extra=meta, positives=positives)
