"""Writing a describe output file (``.h5``/``.hdf5`` or ``.npy`` + names + provenance) from blocks of rows.

The one writer of describe outputs: :mod:`seqnet.describe.store` hands it the whole array as one
block, :mod:`seqnet.describe.merge` streams shards through it block by block (nothing is held in
memory). The output appears in one rename, the descriptors' own, after its sidecars.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from pathlib import Path

import h5py
import numpy as np

from ..core.errors import ConfigError
from ..core.provenance import sidecar as provenance_sidecar
from ..security.files import atomic_path, write_json_atomic, write_text_atomic

OUT_SUFFIXES = (".h5", ".hdf5", ".npy")


def names_file_for(out: str | os.PathLike[str]) -> Path:
    """The names text file written beside a ``.npy`` output."""
    out = Path(out)
    return out.with_name("names.txt") if out.name == "descriptors.npy" else out.with_name(out.stem + ".names.txt")


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
        out.unlink(missing_ok=True)  # only reached with --overwrite (else an existing output is refused)
        write_text_atomic(names_file_for(out), "\n".join(names) + "\n")
        write_json_atomic(provenance_sidecar(out), prov)
        with atomic_path(out) as tmp, open(tmp, "wb") as f:
            np.lib.format.write_array_header_1_0(f, {"descr": "<f4", "fortran_order": False, "shape": tuple(shape)})
            _copy(blocks, shape, lambda a, block: f.write(block.tobytes()))
        return
    with atomic_path(out) as tmp, h5py.File(tmp, "w") as h:
        ds = h.create_dataset("descriptors", shape=tuple(shape), dtype=np.float32)
        _copy(blocks, shape, lambda a, block: ds.__setitem__(slice(a, a + len(block)), block))
        h.create_dataset("names", data=np.array(names, dtype=object), dtype=h5py.string_dtype())
        h.attrs["config"] = config
        h.attrs["provenance"] = json.dumps(prov, sort_keys=True)


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
