"""Reading and writing the seqnet dataset directory format (see docs/dataset_format.md).

:func:`load_dataset` validates everything it reads and says precisely what is wrong;
:func:`save_dataset` builds the directory next to its target and renames it into place, so a
crash never leaves a half-written dataset.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import DatasetError, OutputError
from ..core.log import logger, warn_once
from ..core.npy import write_npy
from ..core.provenance import described_text
from ..security.arrays import read_npz
from ..security.digests import changed_files, file_digest
from ..security.dirs import read_consistent, recover_dir, write_dir
from ..security.files import atomic_path, save_npy_atomic, write_json_atomic, write_text_atomic
from ..security.inputs import check_name, inside
from ..security.jsonfile import read_json, read_json_object
from ..security.limits import INDEX_MAX, number
from ..security.locks import locked
from ..security.ownership import check_replaceable, write_manifest
from .metakeys import META_KEYS, check_extra_radii, misspelt_keys
from .positives import Positives
from .readers import check_names, read_descriptor_file, read_names, read_npy, read_positions_file
from .traverse import DESCRIPTOR_FILES, FORMAT, POSITION_FILES, Dataset, Traverse

# ----------------------------------------------------------------------------- reading


def load_dataset(path: str | Path, mmap: bool = True) -> Dataset:
    """Load and validate a dataset directory; raise :class:`DatasetError` saying what is wrong. A dataset
    replaced while it is read is read again (one version, never a mix)."""
    ds, digests = read_consistent(Path(path), lambda: _load_dataset(Path(path), mmap), DatasetError)
    changed = changed_files(Path(path), digests)
    if changed:  # the directory format may be edited by hand; the contents were checked all the same
        _say_changed(Path(path), changed)
    ds.path = Path(path)  # what seqnet.evaluate finds it by (leakage checks, the unreduced dataset of a --pca one)
    return ds


def _say_changed(path: Path, changed: list[str]) -> None:
    """Warn (at default verbosity, once per dataset and set of changed files in a process: a command may open a
    dataset more than once) that files of ``path`` are not the ones seqnet wrote."""
    warn_once(("dataset changed", str(path.resolve()), tuple(changed)),
              "%s: %s%s changed since seqnet wrote the dataset (seqnet dataset check %s refuses it); the numbers are "
              "of the files as they are now", path, ", ".join(changed[:3]), " ..." if len(changed) > 3 else "", path)


def recorded_digests(path: str | Path) -> dict[str, Any]:
    """The file hashes seqnet recorded in ``dataset.json`` when it wrote the dataset (empty when none)."""
    try:
        meta = read_json(Path(path) / "dataset.json", "dataset.json")
    except DatasetError:
        return {}
    return (meta.get("checksums") or {}) if isinstance(meta, dict) else {}


def _load_dataset(root: Path, mmap: bool) -> tuple[Dataset, dict[str, Any]]:
    """The dataset of ``root`` and the file hashes recorded with it (``{}`` for a hand-made one)."""
    if not root.exists():
        raise DatasetError(f"dataset directory not found: {root}")
    if not root.is_dir():
        raise DatasetError(f"dataset path is not a directory: {root}")
    meta_path = root / "dataset.json"
    if not meta_path.is_file():
        raise DatasetError(f"{root} is not a seqnet dataset: dataset.json is missing "
                           "(hint: `seqnet synth DIR` writes an example)")
    meta = read_json_object(meta_path, "dataset.json")
    misspelt_keys(meta, meta_path)
    if "radius" not in meta:
        raise DatasetError(f"{meta_path}: missing key 'radius' (localisation radius, metres or frames)")
    radius = number(meta["radius"], f"{meta_path}: radius", 1e-300, 1e300, integer=False)
    trav = meta.get("traverses", {"reference": "reference", "query": "query"})
    if not isinstance(trav, dict) or not all(isinstance(v, str) for v in trav.values()):
        raise DatasetError(f"{meta_path}: 'traverses' must be an object like "
                           '{"reference": "ref", "query": "qry"}')
    sides = {side: inside(root, trav.get(side, side), f"{meta_path}: traverse {side!r}") for side in
             ("reference", "query")}
    ref = load_traverse(sides["reference"], "reference", mmap)
    qry = load_traverse(sides["query"], "query", mmap)
    prov = meta.get("provenance") if isinstance(meta.get("provenance"), dict) else {}
    ref.provenance, qry.provenance = (p if isinstance(p, dict) else None for p in (prov.get("reference"),
                                                                                   prov.get("query")))
    ds = Dataset(
        reference=ref,
        query=qry,
        radius=radius,
        position_unit=meta.get("position_unit"),
        splits=_parse_splits(meta.get("splits", {}), meta_path),
        name=_dataset_name(meta, root, meta_path),
        extra={k: v for k, v in meta.items() if k not in META_KEYS},
        positives=load_positives(root / POSITIVES_FILE) if (root / POSITIVES_FILE).is_file() else None,
    )
    return ds, (meta.get("checksums") or {})


def _dataset_name(meta: dict[str, Any], root: Path, meta_path: Path) -> str:
    """The name ``dataset.json`` records; for a dataset named after the folder seqnet wrote it into (``folder``)
    and since copied or renamed, the folder it is in now (``cp -r ds ds_edit``: ``ds_edit``, not ``ds``). A dataset
    seqnet wrote before it recorded the folder (it has ``checksums`` but no ``folder``) in a folder of another name
    is named by both: ``ds_edit (written as ds)``."""
    recorded = check_name(str(meta.get("name", root.name)), f"{meta_path}: name")
    folder, here = meta.get("folder"), Path(os.path.abspath(root)).name
    if not here or here == recorded:
        return recorded
    if isinstance(folder, str) and folder == recorded:
        logger.debug("dataset %s was written as %s: named %s", root, recorded, here)
        return check_name(here, f"{root}: name")
    if folder is None and "checksums" in meta:
        return check_name(f"{here} (written as {recorded})", f"{root}: name")
    return recorded


POSITIVES_FILE = "positives.npz"


def load_positives(f: Path) -> Positives:
    """Explicit positives saved by :func:`save_dataset` (``indptr``, ``indices`` arrays, and ``soft_indptr``,
    ``soft_indices`` when there are soft positives; no pickles)."""
    arrays = read_npz(f, "explicit positives", keys=("indptr", "indices", "soft_indptr", "soft_indices"))
    if "indptr" not in arrays or "indices" not in arrays:
        raise DatasetError(f"cannot read {f} (explicit positives: arrays indptr and indices; found {sorted(arrays)})")
    hard = _csr(arrays["indptr"], arrays["indices"], f, "")
    if "soft_indptr" not in arrays:
        return hard
    soft = _csr(arrays["soft_indptr"], arrays.get("soft_indices", np.zeros(0, np.int64)), f, "soft_")
    if len(soft) != len(hard):
        raise DatasetError(f"{f}: {len(soft)} rows of soft positives for {len(hard)} rows of positives")
    return Positives(hard.indptr, hard.indices, soft=soft)


def _csr(indptr: np.ndarray, indices: np.ndarray, f: Path, prefix: str) -> Positives:
    if indptr.ndim != 1 or indices.ndim != 1 or indptr.dtype.kind not in "iu" or indices.dtype.kind not in "iu":
        raise DatasetError(f"{f}: {prefix}indptr and {prefix}indices must be 1-D integer arrays")
    if indptr.size == 0 or indptr[0] != 0 or (np.diff(indptr) < 0).any() or indptr[-1] != indices.size:
        raise DatasetError(f"{f}: {prefix}indptr must start at 0, never decrease and end at len({prefix}indices)")
    if indices.size and indices.min() < 0:
        raise DatasetError(f"{f}: {prefix}indices (reference indices) must be >= 0")
    return Positives(indptr.astype(np.int64), indices.astype(np.int64))


def _parse_splits(raw: Any, where: Path) -> dict[str, dict[str, tuple[int, int]]]:
    if not isinstance(raw, dict):
        raise DatasetError(f"{where}: 'splits' must be an object like {{\"test\": [0, 100]}}")
    out: dict[str, dict[str, tuple[int, int]]] = {}
    for name, rng in raw.items():
        try:
            if isinstance(rng, dict):  # {"query": [a, b]} alone: the whole reference (filled in by Dataset)
                out[name] = {k: _range(rng[k], f"{where}: split {name!r} {k}") for k in ("reference", "query")
                             if k in rng or k == "query"}
            else:
                a, b = _range(rng, f"{where}: split {name!r}")
                out[name] = {"reference": (a, b), "query": (a, b)}
        except (KeyError, TypeError, IndexError) as err:
            raise DatasetError(
                f"{where}: split {name!r} must be [start, stop] or "
                "{\"reference\": [start, stop], \"query\": [start, stop]}"
            ) from err
    return out


def _range(rng: Any, what: str) -> tuple[int, int]:
    """``[start, stop]`` read from a file: two integers in ``0..INDEX_MAX``."""
    if not isinstance(rng, (list, tuple)) or len(rng) != 2:
        raise TypeError(what)
    return (int(number(rng[0], what, 0, INDEX_MAX)), int(number(rng[1], what, 0, INDEX_MAX)))


def load_traverse(path: Path, name: str, mmap: bool = True) -> Traverse:
    """Load one traverse directory (descriptors, positions, optional names and seq_bounds)."""
    if not path.is_dir():
        raise DatasetError(f"{name} traverse directory not found: {path}")
    desc, names = load_descriptors(path, mmap)
    pos = _load_positions(path)
    if (path / "names.txt").is_file():
        names = read_names(path / "names.txt")
    bounds = None
    if (path / "seq_bounds.npy").is_file():
        bounds = read_npy(path / "seq_bounds.npy", mmap=False)
        if not np.issubdtype(bounds.dtype, np.integer):
            raise DatasetError(f"{path / 'seq_bounds.npy'}: must hold integers, got {bounds.dtype}")
    return Traverse(descriptors=desc, positions=pos, names=names, seq_bounds=bounds, name=f"{name} ({path})")


def load_descriptors(path: Path, mmap: bool = True) -> tuple[np.ndarray, list[str] | None]:
    """The descriptors ``[N, D]`` (and HDF5 names) of a traverse directory: ``descriptors.npy``
    (memory-mapped) or ``descriptors.h5`` / ``.hdf5``."""
    for fname in DESCRIPTOR_FILES:
        if (path / fname).is_file():
            return read_descriptor_file(path / fname, mmap=mmap)
    raise DatasetError(f"no descriptor file in {path}; expected one of {', '.join(DESCRIPTOR_FILES)}")


def _load_positions(path: Path) -> np.ndarray:
    for fname in POSITION_FILES:
        if (path / fname).is_file():
            return read_positions_file(path / fname)
    raise DatasetError(f"no positions file in {path}; expected one of {', '.join(POSITION_FILES)}")


# ----------------------------------------------------------------------------- writing


def is_dataset_file(rel: str) -> bool:
    """Whether ``rel`` (a path inside a dataset directory) is a file seqnet writes there."""
    parts = rel.split("/")
    if parts in (["dataset.json"], [POSITIVES_FILE]):
        return True
    files = (*DESCRIPTOR_FILES, *POSITION_FILES, "names.txt", "seq_bounds.npy")
    return len(parts) == 2 and parts[0] in ("reference", "query") and parts[1] in files


def save_dataset(ds: Dataset, path: str | Path, overwrite: bool = False, quiet: bool = False) -> Path:
    """Write ``ds`` in the directory format; never leaves a half-written dataset behind.

    Everything is written into a temporary sibling directory which is then renamed onto ``path``,
    under the directory's lock (a second writer is refused). ``overwrite`` replaces an existing
    dataset only when every file in it was written by seqnet (listed in its manifest); the old
    directory is renamed aside and deleted only after the new one is in place. ``quiet``: the line saying so is
    DEBUG, not INFO (the caller says it, with more).
    """
    root = Path(path)
    check_extra_radii(ds.extra)
    with locked(root):
        recover_dir(root)
        if root.exists() and (not root.is_dir() or any(root.iterdir())):
            if not overwrite and root.is_dir():
                raise OutputError(f"output directory {root} exists and is not empty (use --overwrite to replace it)")
            check_replaceable(root, "dataset", is_dataset_file)
        write_dir(root, lambda tmp: _write_dataset(ds, tmp, Path(os.path.abspath(root)).name))
    logger.log(logging.DEBUG if quiet else logging.INFO, "wrote dataset %s (reference %d, query %d images; "
               "descriptors %s)", root, len(ds.reference), len(ds.query),
               described_text(ds.reference.provenance) or f"D={ds.reference.dim}")
    return root


def _write_dataset(ds: Dataset, root: Path, folder: str) -> None:
    """``ds`` written into ``root`` (a temporary directory renamed to the folder named ``folder`` afterwards)."""
    for side, t in (("reference", ds.reference), ("query", ds.query)):
        save_traverse(t, root / side)
    if ds.positives is not None:
        with atomic_path(root / POSITIVES_FILE) as tmp, open(tmp, "wb") as f:
            soft = ds.positives.soft
            extra = {} if soft is None else {"soft_indptr": soft.indptr, "soft_indices": soft.indices}
            np.savez(f, indptr=ds.positives.indptr, indices=ds.positives.indices, **extra)
    meta = {
        **{k: v for k, v in ds.extra.items() if k not in META_KEYS},
        "checksums": {p.relative_to(root).as_posix(): file_digest(p, full=True) for p in sorted(root.rglob("*"))
                      if p.is_file()},
        "format": FORMAT,
        "name": ds.name,
        "folder": folder,
        "radius": ds.radius,
        "position_unit": ds.position_unit,
        "splits": {k: {s: list(v[s]) for s in ("reference", "query")} for k, v in ds.splits.items()},
        "provenance": {"reference": ds.reference.provenance, "query": ds.query.provenance},
    }
    write_json_atomic(root / "dataset.json", meta)
    write_manifest(root, "dataset", [p for p in root.rglob("*") if p.is_file()])



def save_traverse(t: Traverse, path: Path) -> None:
    """Write one traverse directory (descriptors.npy, positions.npy, names.txt, seq_bounds.npy)."""
    path.mkdir(parents=True, exist_ok=True)
    desc = t.descriptors
    if desc.dtype != np.float32 or not desc.flags.c_contiguous:
        desc = np.ascontiguousarray(desc, dtype=np.float32)
    with atomic_path(path / "descriptors.npy") as tmp, open(tmp, "wb") as f:
        write_npy(f, desc)  # a streamed memory map (a spill) in blocks
    save_npy_atomic(path / "positions.npy", t.positions)
    if t.names is not None:
        check_names(t.names, f"{t.name}: image names")
        write_text_atomic(path / "names.txt", "\n".join(t.names) + "\n")
    if t.seq_bounds is not None:
        save_npy_atomic(path / "seq_bounds.npy", t.seq_bounds)
