"""Bounded memory over large arrays: memory maps read in blocks, and temporary *spill* files.

A memory-mapped array's pages count in a process's resident set once read. Streaming a map of many
gigabytes block by block would leave every page resident; so blocks of a *streamed* array (a memory
map over more than :data:`RESIDENT_BYTES`) are copied out and their pages released
(``madvise(MADV_DONTNEED)``: the file's pages stay in the page cache, this process stops holding them).
Smaller maps stay resident, as an online localiser wants them.

A derived array too large to hold (:data:`SPILL_BYTES`: e.g. the normalised descriptors of a whole
reference traverse) is written block by block to a *spill*: an anonymous temporary file (unlinked at
once, so nothing is left behind, even after a crash), read back as a read-only memory map that is
always streamed.
"""

from __future__ import annotations

import mmap
import os
import tempfile

import numpy as np

from .errors import ConfigError, ResourceError
from .memory import BLOCK_BYTES

RESIDENT_BYTES = 256 << 20  # memory maps up to this size may stay resident; larger ones are streamed
SPILL_BYTES = 256 << 20  # derived arrays above this go to a spill file instead of memory
TAKE_BYTES = BLOCK_BYTES  # rows gathered per run by take_rows
PAGE = mmap.PAGESIZE


def limit(name: str) -> int:
    """:data:`RESIDENT_BYTES` or :data:`SPILL_BYTES`, or its override in MiB from the environment
    (``SEQNET_RESIDENT_MB``, ``SEQNET_SPILL_MB``: a smaller machine, or a test)."""
    env = os.environ.get(f"SEQNET_{name}_MB")
    if env is None:
        return RESIDENT_BYTES if name == "RESIDENT" else SPILL_BYTES
    try:
        return max(0, int(float(env) * 2**20))
    except ValueError as e:
        raise ConfigError(f"SEQNET_{name}_MB must be a number of MiB, got {env!r}") from e


class Spilled(np.memmap):
    """A read-only ``[N, D]`` memory map over an unlinked temporary file (see :class:`SpillWriter`): always streamed."""


def mapping(x: object) -> mmap.mmap | None:
    """The ``mmap`` behind a numpy memory map (or a view of one), else None."""
    return getattr(x, "_mmap", None) if isinstance(x, np.memmap) else None


def streamed(x: object) -> bool:
    """``x`` is a spill, or a view of a memory map over more than :func:`limit` ``("RESIDENT")`` bytes: release
    its pages after reading a block."""
    mm = mapping(x)
    return mm is not None and (isinstance(x, Spilled) or len(mm) > limit("RESIDENT"))


def release(view: np.ndarray) -> None:
    """Stop holding the pages of ``view`` (a contiguous part of a read-only memory map) in this process.

    The data are not changed: the next read faults them in again from the page cache or the file.
    A no-op for arrays that are no memory map and where ``madvise`` is missing.
    """
    mm = mapping(view)
    if mm is None or view.size == 0 or not hasattr(mm, "madvise"):
        return
    base = np.frombuffer(mm, np.uint8).ctypes.data
    start = (view.ctypes.data - base) // PAGE * PAGE
    end = min(len(mm), view.ctypes.data - base + view.nbytes)
    mm.madvise(mmap.MADV_DONTNEED, start, end - start)


def read_rows(x: np.ndarray, a: int, b: int) -> np.ndarray:
    """Rows ``a:b`` of ``x`` as an array this process owns (a streamed map's pages are released after)."""
    block = x[a:b]
    if not streamed(x):
        return block
    out = np.array(block)
    release(block)
    return out


def take_rows(x: np.ndarray, idx: np.ndarray, spill: bool = False) -> np.ndarray:
    """Rows ``idx`` of ``x`` in order, read in sorted runs (a streamed ``x``'s pages released after each);
    with ``spill``, a large result of increasing ``idx`` goes to a spill file (:class:`Spilled`)."""
    idx = np.asarray(idx, dtype=np.int64)
    if not streamed(x) or len(idx) == 0:
        return np.asarray(x[idx])
    step = max(1, TAKE_BYTES // max(1, x[0].nbytes))
    increasing = bool((np.diff(idx) >= 0).all())
    if spill and increasing and spill_size((len(idx), *x.shape[1:]), x.dtype.itemsize):
        writer = SpillWriter((len(idx), x.shape[1]), x.dtype)
        for s in range(0, len(idx), step):
            writer.write(_run(x, idx[s : s + step]))
        return writer.finish()
    order = np.arange(len(idx)) if increasing else np.argsort(idx, kind="stable")
    out = np.empty((len(idx), *x.shape[1:]), x.dtype)
    for s in range(0, len(idx), step):
        part = order[s : s + step]
        out[part] = _run(x, idx[part])
    return out


def _run(x: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Rows ``idx`` (non-decreasing) of the streamed ``x``: the span they cover is read, then released."""
    lo, hi = int(idx[0]), int(idx[-1]) + 1
    span = x[lo:hi]
    out = span[idx - lo]
    release(span)
    return out


class SpillWriter:
    """Write ``[N, D]`` rows block by block into an unlinked temporary file; :meth:`finish` maps it.

    Args:
        shape: ``(N, D)``; dtype: numpy dtype; what: for the error when there is no room.
    """

    def __init__(self, shape: tuple[int, int], dtype: np.dtype | str, what: str = "descriptors") -> None:
        from .memory import check_space

        self.shape, self.dtype = (int(shape[0]), int(shape[1])), np.dtype(dtype)
        folder = os.environ.get("SEQNET_SPILL_DIR") or tempfile.gettempdir()
        nbytes = self.shape[0] * self.shape[1] * self.dtype.itemsize
        check_space(folder, nbytes, f"{what} spilled to a temporary file", largest=nbytes)
        try:
            self.file = tempfile.TemporaryFile(dir=folder, prefix="seqnet-spill-")
        except OSError as e:
            raise ResourceError(f"cannot make a temporary file in {folder} for {what}: {e.strerror}; "
                                "hint: set SEQNET_SPILL_DIR to a writable folder") from e
        self.rows = 0

    def write(self, block: np.ndarray) -> None:
        """Append ``block [n, D]`` (cast to the spill's dtype)."""
        block = np.ascontiguousarray(block, dtype=self.dtype)
        if block.ndim != 2 or block.shape[1] != self.shape[1] or self.rows + len(block) > self.shape[0]:
            raise ValueError(f"spill block of shape {block.shape} does not fit {self.shape} at row {self.rows}")
        try:
            self.file.write(block.data)
        except OSError as e:
            self.file.close()
            raise ResourceError(f"writing a temporary spill file failed: {e.strerror}; "
                                "hint: set SEQNET_SPILL_DIR to a folder with room") from e
        self.rows += len(block)

    def finish(self, short: bool = False) -> Spilled:
        """The rows written, as a read-only streamed memory map (the file goes when the map does);
        ``short``: fewer rows than ``shape`` may have been written (the map holds those)."""
        if self.rows != self.shape[0] and not short:
            raise ValueError(f"spill holds {self.rows} of {self.shape[0]} rows")
        shape = (self.rows, self.shape[1])
        self.file.flush()
        if self.rows == 0:
            self.file.close()
            return np.zeros(shape, self.dtype).view(Spilled)
        out = Spilled(self.file, dtype=self.dtype, mode="r", shape=shape)
        self.file.close()  # the mapping keeps the (unlinked) file alive
        return out


def spill_size(shape: tuple[int, ...], itemsize: int = 4) -> bool:
    """An array of ``shape`` and ``itemsize`` is large enough to spill (more than :func:`limit` ``("SPILL")``)."""
    return int(np.prod(shape)) * itemsize > limit("SPILL")


class RowsOut:
    """``[N, D]`` rows filled in order, block by block: an array, or a spill file (:class:`SpillWriter`) when
    ``spill`` and the whole would be over :func:`limit` ``("SPILL")``."""

    def __init__(self, shape: tuple[int, int], dtype: np.dtype | str, spill: bool) -> None:
        dtype = np.dtype(dtype)
        self.writer = SpillWriter(shape, dtype) if spill and spill_size(shape, dtype.itemsize) else None
        self.buf = None if self.writer else np.empty(shape, dtype)
        self.rows = 0

    def put(self, block: np.ndarray) -> None:
        """Append ``block [n, D]``."""
        if self.writer is not None:
            self.writer.write(block)
        else:
            self.buf[self.rows : self.rows + len(block)] = block
        self.rows += len(block)

    def slot(self, n: int) -> np.ndarray | None:
        """The next ``n`` rows of the held array, to be filled in place (counted as put), or None when spilling
        (then :meth:`put` them): a block computed straight into its rows, no second copy."""
        if self.writer is not None:
            return None
        self.rows += n
        return self.buf[self.rows - n : self.rows]

    def finish(self, short: bool = False) -> np.ndarray:
        """The array (held) or a read-only :class:`Spilled` map; ``short``: only the rows put (fewer than N)."""
        if self.writer is not None:
            return self.writer.finish(short=short)
        return self.buf[: self.rows] if short else self.buf
