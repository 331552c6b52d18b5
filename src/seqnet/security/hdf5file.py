"""Reading an HDF5 file from anywhere: libhdf5 runs in a sandboxed child, never in this process.

libhdf5 follows external links and external storage to other files, maps virtual datasets, allocates
what a header declares and can crash the interpreter on a malformed file. :func:`read_hdf5` runs it in
a child process (:mod:`seqnet.security.sandbox`, reader :mod:`seqnet.security.hdf5_child`) bounded in
memory and time; this process only receives plain arrays and strings, checks each announced shape
against its own bound before allocating, and reads the bytes into the array. :func:`check_hdf5` reads
a file through once in the child (every byte decoded) before this process opens it with ``h5py``
itself (describe's own partial files, which it appends to).
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path
from typing import IO, Any

import numpy as np

from ..core.errors import DatasetError
from ..core.memory import available_bytes
from .arrays import MAX_RATIO
from .inputs import ErrorType, open_input
from .sandbox import run_child, time_bound

SLAB_MEMORY = 96 << 20


@dataclasses.dataclass
class Hdf5Contents:
    """What an HDF5 file holds: numeric ``arrays`` and string datasets (``strings``, flat lists) by path,
    the root ``attrs`` that are text or numbers, the ``groups``, and the datasets ``skipped`` (other types)."""

    arrays: dict[str, np.ndarray]
    strings: dict[str, list[str]]
    attrs: dict[str, Any]
    groups: list[str]
    skipped: list[str]

    def names(self) -> list[str]:
        """Every dataset's path."""
        return sorted({*self.arrays, *self.strings, *self.skipped})


def _size(path: str | os.PathLike[str], what: str, error: ErrorType) -> int:
    with open_input(path, what, error) as f:  # a FIFO or device is refused here, before a child starts
        return os.fstat(f.fileno()).st_size


def read_hdf5(path: str | os.PathLike[str], what: str = "HDF5 file", error: ErrorType = DatasetError,
              attrs_only: bool = False) -> Hdf5Contents:
    """Everything of ``path`` that is numbers or text (``attrs_only``: the root attributes alone), read in the
    sandbox; ``error`` names the file and what is wrong."""
    size = _size(path, what, error)
    limit = max(1 << 20, min(available_bytes() or 1 << 34, size * MAX_RATIO + (1 << 20)))
    request = {"path": str(Path(path).absolute()), "mode": "attrs" if attrs_only else "data", "limit": limit}
    with run_child("hdf5", request, f"{what} {path}", SLAB_MEMORY + 4 * size, time_bound(size), error) as (ans, s):
        if attrs_only:
            return Hdf5Contents({}, {}, _mapping(ans.get("attrs")), [], [])
        arrays = _receive(ans.get("arrays"), s, limit, f"{what} {path}", error)
        strings = {str(k): [str(x) for x in v] for k, v in _mapping(ans.get("strings")).items() if isinstance(v, list)}
        return Hdf5Contents(arrays, strings, _mapping(ans.get("attrs")),
                            [str(g) for g in ans.get("groups") or []], [str(g) for g in ans.get("skipped") or []])


def check_hdf5(path: str | os.PathLike[str], what: str = "HDF5 file", error: ErrorType = DatasetError) -> None:
    """Read ``path`` through in the sandbox (every dataset decoded, nothing kept): ``error`` when libhdf5
    refuses, crashes or overruns on it, so that this process may then open it itself."""
    size = _size(path, what, error)
    request = {"path": str(Path(path).absolute()), "mode": "check", "limit": size * MAX_RATIO + (1 << 20)}
    with run_child("hdf5", request, f"{what} {path}", SLAB_MEMORY + 4 * size, time_bound(size), error):
        pass




def _mapping(value: Any) -> dict[str, Any]:
    return {str(k): v for k, v in value.items()} if isinstance(value, dict) else {}


def _receive(meta: Any, stream: IO[bytes], limit: int, what: str, error: ErrorType) -> dict[str, np.ndarray]:
    """The announced arrays, each checked (plain numbers, total within ``limit``) before it is allocated."""
    items = meta if isinstance(meta, list) else []
    shapes = []
    for item in items:
        try:
            dtype = np.dtype(str(item["dtype"]))
            shape = tuple(int(s) for s in item["shape"])
        except (KeyError, TypeError, ValueError) as e:
            raise error(f"cannot read {what}: its reader announced {item!r}") from e
        if dtype.kind not in "biuf" or dtype.fields is not None or any(s < 0 for s in shape):
            raise error(f"cannot read {what}: its reader announced {shape} of {dtype}")
        shapes.append((str(item["name"]), shape, dtype))
    total = sum(math.prod(s) * d.itemsize for _, s, d in shapes)
    if total > limit:
        raise error(f"cannot read {what}: it holds {total} bytes of numbers, more than the {limit} allowed")
    out = {}
    for name, shape, dtype in shapes:
        arr = np.empty(shape, dtype=dtype)
        flat, got = memoryview(arr.reshape(-1)).cast("B"), 0
        while got < arr.nbytes:
            n = stream.readinto(flat[got:])
            if not n:
                raise error(f"cannot read {what}: its reader stopped early (at dataset {name!r})")
            got += n
        out[name] = arr
    return out
