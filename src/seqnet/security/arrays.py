"""Reading ``.npy`` and ``.npz`` arrays: the header is checked against the file's real bytes first.

``np.load`` trusts a header: a 100-byte ``.npy`` declaring ``[10**6, 10**5]`` floats allocates 373 GiB
before it finds the data missing, and an ``.npz`` member is allocated whole before it is decompressed.
Here the header is parsed first (at most 64 KiB, format 1.0 or 2.0), its dtype must be plain numbers
(bool, integers, floats; no objects, fields or sub-arrays: nothing that unpickles), and its shape times
the item size must fit in the bytes really there: the file's size, or for an ``.npz`` member the bytes
its archive can decompress to (at most :data:`MAX_RATIO` times the compressed size). Only then is the
array memory-mapped or read.
"""

from __future__ import annotations

import math
import os
import zipfile
import zlib
from collections.abc import Iterable
from pathlib import Path
from typing import BinaryIO

import numpy as np

from ..core.errors import DatasetError
from .inputs import ErrorType, open_input

MAX_HEADER = 1 << 16
MAX_RATIO = 1100  # deflate's largest expansion is 1032:1
NUMERIC_KINDS = "biuf"


def read_header(f: BinaryIO, where: str, error: ErrorType = DatasetError) -> tuple[tuple[int, ...], bool, np.dtype]:
    """``(shape, fortran_order, dtype)`` of the ``.npy`` header at the position of ``f`` (left at the data)."""
    magic = f.read(6)
    if magic != b"\x93NUMPY":
        what = "empty" if not magic else "a .npz archive" if magic.startswith(b"PK") else \
            "not in .npy format (no NumPy header)"
        raise error(f"cannot read {where} as a .npy array: the file is {what}")
    version = tuple(f.read(2))
    readers = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
    if version not in readers:
        raise error(f"cannot read {where}: .npy format version {version} is not read here (1.0 and 2.0 are)")
    try:
        shape, fortran, dtype = readers[version](f, max_header_size=MAX_HEADER)
    except Exception as e:  # noqa: BLE001 - numpy's header parser raises ValueError, SyntaxError, TokenError ...
        raise error(f"cannot read {where}: its .npy header is malformed ({' '.join(str(e).split())[:200]})") from e
    if not isinstance(shape, tuple) or not all(isinstance(s, int) and s >= 0 for s in shape):
        raise error(f"cannot read {where}: its .npy header declares the shape {shape!r}")
    return shape, bool(fortran), dtype


def check_dtype(dtype: np.dtype, where: str, error: ErrorType = DatasetError, kinds: str = NUMERIC_KINDS) -> None:
    """Plain numbers of a kind in ``kinds``: objects (pickles), records, sub-arrays and strings are refused."""
    if dtype.hasobject:
        raise error(f"cannot read {where} as a .npy array (it holds Python objects (pickled data), not numbers)")
    if dtype.fields is not None or dtype.subdtype is not None or dtype.kind not in kinds:
        want = "floating point numbers" if kinds == "f" else f"numbers (kinds {kinds!r})"
        raise error(f"cannot read {where}: its values must be {want}, got dtype {dtype} (hint: save them as float32)")


def nbytes_of(shape: tuple[int, ...], dtype: np.dtype) -> int:
    """Bytes of an array of ``shape`` and ``dtype``, in Python integers (no overflow)."""
    return math.prod(shape) * dtype.itemsize


def read_npy(path: str | os.PathLike[str], mmap: bool | str = True, what: str = "array",
             error: ErrorType = DatasetError, kinds: str = NUMERIC_KINDS) -> np.ndarray:
    """The array of a ``.npy`` file (``mmap``: memory-mapped read-only; ``"c"``: copy-on-write), after the
    checks of the module docstring; ``error`` names the file and what is wrong."""
    where = str(path)
    with open_input(path, what, error) as f:
        shape, fortran, dtype = read_header(f, where, error)
        check_dtype(dtype, where, error, kinds)
        offset, size = f.tell(), os.fstat(f.fileno()).st_size
        need = nbytes_of(shape, dtype)
        if need > size - offset:
            raise error(f"cannot read {where}: its header declares {shape} of {dtype} ({need} bytes) but the file "
                        f"holds {size - offset} bytes of data (truncated or damaged)")
        order = "F" if fortran else "C"
        if mmap and need:
            return np.memmap(f, dtype=dtype, mode="c" if mmap == "c" else "r", offset=offset, shape=shape,
                             order=order)
        out = np.empty(shape, dtype=dtype, order=order)
        if need and f.readinto(memoryview(out.reshape(-1, order="A")).cast("B")) != need:
            raise error(f"cannot read {where}: the file ended early")
    return out


def read_npz(path: str | os.PathLike[str], what: str = "archive", error: ErrorType = DatasetError,
             kinds: str = NUMERIC_KINDS, keys: Iterable[str] | None = None) -> dict[str, np.ndarray]:
    """The arrays of an ``.npz`` file by name (``np.savez`` / ``savez_compressed``; ``keys``: only those, the
    others left unread), each member checked as the module docstring says before it is allocated."""
    wanted = None if keys is None else set(keys)
    out: dict[str, np.ndarray] = {}
    with open_input(path, what, error) as f:
        size = os.fstat(f.fileno()).st_size
        try:
            with zipfile.ZipFile(f) as z:
                for info in z.infolist():
                    name = info.filename[:-4]
                    if info.filename.endswith(".npy") and not info.is_dir() and (wanted is None or name in wanted):
                        out[name] = _member(z, info, f"{path}:{info.filename}", size, error, kinds)
        except (zipfile.BadZipFile, zipfile.LargeZipFile, NotImplementedError, EOFError, OSError, ValueError,
                zlib.error) as e:
            raise error(f"cannot read {path} as an .npz archive ({' '.join(str(e).split())[:200]})") from e
    return out


def _member(z: zipfile.ZipFile, info: zipfile.ZipInfo, where: str, size: int, error: ErrorType,
            kinds: str) -> np.ndarray:
    """One member of an ``.npz``: its header checked, then its data read into an array of the declared size."""
    bound = min(info.file_size, max(info.compress_size, 0) * MAX_RATIO + MAX_HEADER, size * MAX_RATIO + MAX_HEADER)
    if info.flag_bits & 0x1:
        raise error(f"cannot read {where}: the archive member is encrypted (numpy never writes one)")
    with z.open(info) as m:
        shape, fortran, dtype = read_header(m, where, error)
        check_dtype(dtype, where, error, kinds)
        need = nbytes_of(shape, dtype)
        if need > bound:
            raise error(f"cannot read {where}: its header declares {shape} of {dtype} ({need} bytes), more than "
                        f"the archive holds ({bound} bytes at most)")
        out = np.empty(shape, dtype=dtype, order="F" if fortran else "C")
        flat = memoryview(out.reshape(-1, order="A")).cast("B") if need else memoryview(b"")
        got = 0
        while got < need:
            n = m.readinto(flat[got:])
            if not n:
                raise error(f"cannot read {where}: the archive member ended early")
            got += n
    return out


def is_npy(path: str | Path) -> bool:
    """Whether ``path`` starts like a ``.npy`` file (read without blocking; False when it cannot be read)."""
    try:
        with open_input(path) as f:
            return f.read(6) == b"\x93NUMPY"
    except (OSError, DatasetError):
        return False
