"""Build datasets from CSV files, descriptor files and UTM-coded image names.

Inputs, per traverse (reference and query):

* a descriptor file ``[N, D]``: ``.npy`` (image names from a names file, one per line, given or kept beside
  it: ``FILE.names.txt``, as ``seqnet describe`` writes) or HDF5 (``.h5`` / ``.hdf5``: dataset ``descriptors``
  and optional ``names``);
* positions, either from a CSV file (:mod:`.csvfile`: a header row naming an image column and ``easting,
  northing`` in metres, ``lat, lon`` in degrees (unit ``degrees``: :func:`traverses_in_metres` makes both UTM
  metres), or ``frame``; rows are matched to the descriptors by image name (:mod:`.names`), and an optional
  ``sequence`` column gives sequence bounds), or from the image names themselves when they carry
  UTM coordinates as ``@<easting>@<northing>@...`` (Pittsburgh, Tokyo 24/7, MSLS-style names).

Everything here is a pure function of its inputs returning arrays or :class:`Traverse` objects.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ...core.errors import ConfigError, DatasetError
from ...core.log import logger
from ...core.provenance import check_same
from ...security.limits import POSITION_MAX
from ..imagefolders import list_file, utm_positions
from ..positives import Positives
from ..readers import read_descriptor_file, read_provenance, transposed_hint, warn_unless_unit_rows
from ..spacing import LONG_STEPS, crossing_steps, many_crossing, order_hint
from ..traverse import Dataset, Traverse
from ..utm import latlon_pair
from .csvfile import (
    FRAME_COLUMNS,
    NAME_COLUMNS,
    SEQUENCE_COLUMNS,
    PositionsTable,
    agreed_kinds,
    read_csv_rows,
    read_positions_csv,
    read_positions_table,
    read_seq_bounds,
    runs_to_bounds,
    sequence_bounds,
)
from .names import CsvNames, match_names, warn_reordered

__all__ = [
    "FRAME_COLUMNS", "NAME_COLUMNS", "POSITION_MAX", "SEQUENCE_COLUMNS", "CsvNames", "agreed_kinds", "assemble_dataset",
    "match_names", "names_flag", "positives_radius", "read_csv_rows", "read_positions_csv",
    "read_positions_table", "read_seq_bounds",
    "runs_to_bounds", "sequence_bounds", "traverse_from_csv", "traverse_from_utm_names", "traverses_in_metres",
    "warn_reordered",
]

def names_flag(name: str) -> str:
    """The flag that gives the image names of the traverse called ``name`` (``reference ...`` / ``query ...``)."""
    return "--ref-names" if name.startswith("ref") else "--query-names" if name.startswith("query") else \
        "--ref-names / --query-names"


def traverse_from_csv(csv_path: str | Path, desc_path: str | Path, names_file: str | Path | None = None,
                      name: str = "traverse") -> tuple[Traverse, str]:
    """A traverse from a positions CSV and a descriptor file; also the unit.

    The descriptors' image names (HDF5 ``names``, ``names_file``, else the names kept beside a ``.npy``:
    :func:`seqnet.data.readers.names_beside`) are matched to the CSV's rows; the traverse follows the
    descriptors' order (the order the images were described in, as ``from-images`` follows its images), the
    CSV places them (a CSV in another order is said). Without names, row i is descriptor i (same count; said).
    """
    table = read_positions_table(csv_path)
    desc, desc_names = read_descriptor_file(desc_path, names_file, beside=True)
    if desc_names is None:
        rows = _paired_by_order(table, desc, csv_path, desc_path, name)
        picked = rows
    else:
        idx = match_names(table.names, desc_names, f"{csv_path} vs {desc_path}")
        rows = np.argsort(idx, kind="stable")  # the CSV's rows in the descriptors' order
        picked = idx[rows]
        moved = np.flatnonzero(rows != np.arange(len(rows)))
        if moved.size:
            k = int(moved[0])
            logger.warning("%s lists its images in another order than %s (line %d, %r, is descriptor %d); the %s "
                           "follows the descriptors' order (the order the images were described in), the CSV only "
                           "places them; hint: if the CSV's order is the route's, describe the images in that order "
                           "(seqnet describe LIST_FILE)", csv_path, desc_path, table.names.lines[k], table.names[k],
                           int(idx[k]), name)
    d = desc if np.array_equal(picked, np.arange(desc.shape[0])) else np.asarray(desc[picked])
    bounds = None if table.keys is None else sequence_bounds([table.keys[i] for i in rows], str(table.column))
    return Traverse(descriptors=d, positions=table.positions[rows], names=[table.names[i] for i in rows],
                    seq_bounds=bounds, name=name, provenance=read_provenance(desc_path)), table.unit


def _paired_by_order(table: PositionsTable, desc: np.ndarray, csv_path: str | Path, desc_path: str | Path,
                     name: str) -> np.ndarray:
    """Row i of the CSV is descriptor i (no descriptor names): the rows, after checking the counts and saying so."""
    n = len(table.names)
    if n != desc.shape[0]:
        raise DatasetError(f"{csv_path}: {n} rows but {desc_path} holds {desc.shape[0]} descriptors"
                           + (transposed_hint(n, desc) or f" and no names; hint: give a names file "
                              f"({names_flag(name)}) or HDF5 'names' to match by name"))
    logger.warning("%s: its rows are paired with the descriptors of %s by order (row i is descriptor i), not by its "
                   "image names (%s has none): the rows must be in the descriptors' order; hint: a names file "
                   "(%s) or HDF5 'names' pairs them by name", csv_path, desc_path, desc_path, names_flag(name))
    return np.arange(n)


def traverses_in_metres(ref: Traverse, qry: Traverse, files: tuple[str, str]) -> tuple[Traverse, Traverse, str]:
    """Both traverses with their lat/lon positions (unit ``degrees``, read from ``files``) as UTM metres, the
    query in the reference's zone (:func:`seqnet.data.utm.latlon_pair`); and that positions frame."""
    import dataclasses

    r, q, frame = latlon_pair(ref.positions, qry.positions, (str(files[0]), str(files[1])))
    return dataclasses.replace(ref, positions=r), dataclasses.replace(qry, positions=q), frame


def traverse_from_utm_names(desc_path: str | Path, names_file: str | Path | None = None,
                            name: str = "traverse") -> Traverse:
    """A traverse whose positions are parsed from UTM-coded image names (HDF5 names or a names file)."""
    desc, names = read_descriptor_file(desc_path, names_file, beside=True)
    if names is None:
        raise DatasetError(f"{desc_path}: no image names; give a names file ({names_flag(name)} FILE), an HDF5 "
                           "file with a 'names' dataset, or a .npy with its names file beside it (FILE.names.txt, "
                           "as seqnet describe writes)")
    warn_unless_unit_rows(desc, desc_path)
    positions = utm_positions(names)
    if names_file is not None and Path(names_file).is_dir() and not list_file(Path(names_file)).exists():
        warn_name_order(Path(names_file), names, positions)
    return Traverse(descriptors=desc, positions=positions, names=names, name=name,
                    provenance=read_provenance(desc_path))


def warn_name_order(folder: Path, names: list[str], positions: np.ndarray) -> bool:
    """Warn (and return True) when the UTM-coded ``names`` of ``folder`` in sorted order (VPR-methods-evaluation's
    rule without a list file), at ``positions [N, 2]``, take many steps that pass over the route's own frames
    (:func:`seqnet.data.spacing.crossing_steps`): the names begin with their coordinates, so the frames follow
    the coordinates' text (unpadded, ``@1000@`` sorts before ``@100@``), not the drive, and sequence methods see
    that order. A drive in name order that changes speed or has a gap is silent."""
    found, n, step = crossing_steps(positions, None)
    if not many_crossing(found, n):
        return False
    i = int(found[0])
    logger.warning("%s: the frames follow the sorted image names (VPR-methods-evaluation's rule: sorted(glob), no "
                   "list file %s), which begin with their coordinates, and %d of the %d steps between consecutive "
                   "frames pass over other frames of the route (longer than %g usual steps of %.3g metres, with "
                   "frames at their middle; first: %r, then %r): the frames are in an order of the names' text, not "
                   "the drive's, and sequence methods would see it (hint: %s)", folder, list_file(folder).name,
                   len(found), n, LONG_STEPS, step, names[i], names[i + 1], order_hint(True))
    return True


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
    from ..presets import get_preset, preset_metadata, preset_splits

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
