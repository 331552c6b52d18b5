"""Writing a describe output file (``.h5``/``.hdf5`` or ``.npy`` + names + provenance) from blocks of rows.

The one writer of describe outputs: :mod:`seqnet.describe.stage` hands it the whole array as one
block, :mod:`seqnet.describe.merge` streams shards through it block by block (nothing is held in
memory). The output appears in one rename, the descriptors' own. A ``.npy``'s provenance sidecar records
the size and sampled hash of the descriptors it belongs to and their names (``BOUND_KEY``); it is written
before the descriptors are renamed into place, holding the record of the output it replaces as well, so
whichever descriptors a kill leaves, seqnet pairs them with their own provenance and names
(:func:`seqnet.data.readers.read_provenance`, :func:`seqnet.data.readers.bound_names`); the names text file
for other tools follows the descriptors. Sidecars that seqnet did not write are never replaced
(:func:`check_sidecars`).
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path

import h5py
import numpy as np

from ..core.errors import ConfigError, DatasetError, OutputError
from ..core.memory import HDF5_OVERHEAD, check_space
from ..core.npy import write_npy_rows
from ..core.provenance import BOUND_KEY, MAX_SIDECAR, REPLACES_KEY
from ..core.provenance import sidecar as provenance_sidecar
from ..data.readers import names_file_for  # the one rule, also the converters' (names beside a .npy)
from ..security.digests import file_digest
from ..security.files import atomic_path, write_json_atomic, write_text_atomic
from ..security.jsonfile import read_json

OUT_SUFFIXES = (".h5", ".hdf5", ".npy")


def check_sidecars(out: Path, overwrite: bool = False) -> None:
    """Refuse (:class:`OutputError`) to write the ``.npy`` output ``out`` when a names or provenance file is
    beside it that seqnet did not write with it (a provenance file bound to ``out``'s names file marks both
    as seqnet's), unless ``overwrite``."""
    if out.suffix.lower() != ".npy" or overwrite:
        return
    names, prov = names_file_for(out), provenance_sidecar(out)
    try:
        record = read_json(prov, "provenance file", limit=MAX_SIDECAR) if prov.is_file() else None
    except DatasetError:
        record = None
    bound = record.get(BOUND_KEY) if isinstance(record, dict) else None
    ours = isinstance(bound, dict)  # a provenance file seqnet bound to its descriptors and names
    for f in (names, prov):
        if (f.exists() or f.is_symlink()) and not (ours and f.is_file() and not f.is_symlink()):
            raise OutputError(f"{f} exists and was not written by seqnet with {out.name}; refusing to replace it "
                              "(move it away, or pass --overwrite)")


def write_output(out: Path, shape: tuple[int, int], blocks: Iterable[np.ndarray], names: list[str], config: str,
                 prov: dict) -> None:
    """Write ``shape = (N, D)`` float32 descriptors given as consecutive row ``blocks`` (``[b_i, D]``,
    summing to N), their ``names`` and, for HDF5, the ``config`` JSON, with provenance ``prov``.

    An older output it replaces is removed first, so descriptors never sit beside another run's names
    or provenance; a ``.npy`` is written with ``write()`` calls (a full disk is ENOSPC, not SIGBUS).
    """
    if len(names) != shape[0]:
        raise ConfigError(f"{out}: {len(names)} names for {shape[0]} descriptors")
    if out.suffix.lower() == ".npy":
        _write_npy(out, shape, blocks, names, prov)
        return
    size = HDF5_OVERHEAD + shape[0] * (shape[1] * 4 + 64) + sum(len(n.encode()) for n in names)
    check_space(out.parent, size, f"{shape[0]} descriptors of D={shape[1]} in HDF5", largest=size)  # libhdf5 may
    with atomic_path(out) as tmp, h5py.File(tmp, "w") as h:  # not fail cleanly on a full disk: never let it meet one
        ds = h.create_dataset("descriptors", shape=tuple(shape), dtype=np.float32)
        _copy(blocks, shape, lambda a, block: ds.__setitem__(slice(a, a + len(block)), block))
        h.create_dataset("names", data=np.array(names, dtype=object), dtype=h5py.string_dtype())
        h.attrs["config"] = config
        h.attrs["provenance"] = json.dumps(prov, sort_keys=True)


def _write_npy(out: Path, shape: tuple[int, int], blocks: Iterable[np.ndarray], names: list[str], prov: dict) -> None:
    """The ``.npy`` output and its sidecars, in the order of the module docstring."""
    previous = replaced_record(out)
    with atomic_path(out) as tmp:  # the descriptors renamed last: the old output stays whole until then
        with open(tmp, "wb") as f:
            write_npy_rows(f, shape, "<f4", blocks, "descriptor")
        record = {**prov, BOUND_KEY: {"descriptors": file_digest(tmp), "names": names}}
        write_json_atomic(provenance_sidecar(out), {**record, REPLACES_KEY: previous} if previous else record)
    write_text_atomic(names_file_for(out), "\n".join(names) + "\n")
    if previous:
        write_json_atomic(provenance_sidecar(out), record)


def replaced_record(out: Path) -> dict | None:
    """The sidecar record of the ``.npy`` output now at ``out`` (None when there is none or it is not bound to it)."""
    if not out.is_file() or not provenance_sidecar(out).is_file():
        return None
    try:
        record = read_json(provenance_sidecar(out), "provenance file", limit=MAX_SIDECAR)
    except DatasetError:
        return None
    bound = record.get(BOUND_KEY) if isinstance(record, dict) else None
    if not isinstance(bound, dict) or bound.get("descriptors") != file_digest(out):
        return None
    return {k: v for k, v in record.items() if k != REPLACES_KEY}


def _copy(blocks: Iterable[np.ndarray], shape: tuple[int, int], put) -> None:  # noqa: ANN001 - (row, block) -> None
    """Hand every block, as C-contiguous little-endian float32, to ``put(first row, block)``; the rows must
    add up to ``shape``."""
    row = 0
    for block in blocks:
        block = np.ascontiguousarray(block, dtype="<f4")
        if block.ndim != 2 or block.shape[1] != shape[1] or row + len(block) > shape[0]:
            raise ConfigError(f"a block of shape {block.shape} does not fit rows {row}.. of {tuple(shape)}")
        if len(block):
            put(row, block)
        row += len(block)
    if row != shape[0]:
        raise ConfigError(f"{row} descriptor rows written of the {shape[0]} expected")
