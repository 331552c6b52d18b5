"""The one ``.npy`` writer: every array seqnet writes as ``.npy`` goes through :func:`write_npy_rows`.

The bytes are those ``np.save`` writes (format 1.0, C order), written with ``f.write`` block by block — never
through a memory map, so a full disk is ENOSPC (one line, exit 1), not SIGBUS — and a streamed input (a memory
map, a spill) is read a block at a time with its pages released (:func:`seqnet.core.memmaps.read_rows`).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import BinaryIO

import numpy as np

from . import memmaps
from .errors import ConfigError


def write_npy_rows(f: BinaryIO, shape: tuple[int, ...], dtype: np.dtype | str, blocks: Iterable[np.ndarray],
                   what: str = "array") -> int:
    """Write the header of an array of ``shape`` and ``dtype``, then its rows from ``blocks`` (each
    ``[n, *shape[1:]]``, converted to ``dtype``). Returns the rows written; a block that does not fit or rows that
    do not add up to ``shape[0]`` are a :class:`ConfigError` naming ``what``."""
    dt = np.dtype(dtype)
    if dt.hasobject:
        raise ConfigError(f"{what}: object arrays are not written as .npy (they would need pickle)")
    shape = tuple(int(n) for n in shape)
    np.lib.format.write_array_header_1_0(f, {"descr": np.lib.format.dtype_to_descr(dt), "fortran_order": False,
                                             "shape": shape})
    if not shape:
        block = np.ascontiguousarray(next(iter(blocks)), dtype=dt).reshape(())
        f.write(block.tobytes())
        return 0
    row = 0
    for block in blocks:
        block = np.ascontiguousarray(block, dtype=dt)
        if block.shape[1:] != shape[1:] or row + len(block) > shape[0]:
            raise ConfigError(f"a {what} block of shape {block.shape} does not fit rows {row}.. of {shape}")
        f.write(block.data if block.size else b"")
        row += len(block)
    if row != shape[0]:
        raise ConfigError(f"{row} {what} rows written of the {shape[0]} expected")
    return row


def row_blocks(x: np.ndarray, block_bytes: int | None = None) -> Iterator[np.ndarray]:
    """``x [N, ...]`` in blocks of rows of about ``block_bytes`` (default ``memmaps.TAKE_BYTES``; a streamed ``x``:
    each block read, then released)."""
    step = max(1, (block_bytes or memmaps.TAKE_BYTES) // max(1, x[:1].nbytes))
    for a in range(0, len(x), step):
        yield memmaps.read_rows(x, a, a + step)


def write_npy(f: BinaryIO, x: np.ndarray) -> None:
    """Write ``x`` to the open binary file ``f`` in ``.npy`` format (the bytes ``np.save`` writes)."""
    x = np.asarray(x)
    write_npy_rows(f, x.shape, x.dtype, row_blocks(x) if x.ndim else [x])
