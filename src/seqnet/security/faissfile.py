"""Reading a FAISS index from anywhere: probed in a sandboxed child first, then read read-only.

FAISS allocates what an index header declares and trusts the offsets and neighbour ids it reads, so a
crafted index can exhaust memory, crash the interpreter, or (with on-disk inverted lists) name any file
on the machine to map read-write. :func:`read_faiss` first reads the index in a child process
(:mod:`seqnet.security.sandbox`, :mod:`seqnet.security.faiss_child`), bounded in memory and time, which
checks what a search would dereference; then this process checks what the child reported (the vectors
and D expected, the on-disk lists file being ``<index>.ivfdata`` in the index's own folder, a regular file
holding the lists' bytes) and reads the index with ``IO_FLAG_READ_ONLY | IO_FLAG_ONDISK_SAME_DIR``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from ..core.errors import DatasetError
from .faiss_child import quiet_stdout
from .inputs import ErrorType, open_input
from .sandbox import run_child, time_bound


def read_faiss(path: str | os.PathLike[str], ntotal: int, dim: int, what: str = "FAISS index",
               error: ErrorType = DatasetError) -> Any:
    """The index of ``path`` after the checks of the module docstring; it must hold ``ntotal`` vectors of
    dimension ``dim``."""
    import faiss

    path = Path(path)
    with open_input(path, what, error) as f:
        size = os.fstat(f.fileno()).st_size
    lists = path.with_suffix(".ivfdata")
    if lists.exists() or lists.is_symlink():  # a FIFO there would hang FAISS: refused before it looks
        with open_input(lists, "inverted lists", error, follow=False):
            pass
    with run_child("faiss", {"path": str(path.absolute())}, f"{what} {path}", 4 * size, time_bound(size),
                   error) as (info, _):
        pass
    if info.get("ntotal") != ntotal or info.get("d") != dim:
        raise error(f"{path}: {what} of {info.get('ntotal')} vectors of D={info.get('d')}, the map has {ntotal} "
                    f"of D={dim}")
    ondisk = info.get("ondisk")
    if ondisk is not None:
        _check_lists_file(path, ondisk, error)
    try:
        with quiet_stdout():
            return faiss.read_index(str(path), faiss.IO_FLAG_READ_ONLY | faiss.IO_FLAG_ONDISK_SAME_DIR)
    except RuntimeError as e:
        raise error(f"cannot read {what} {path} ({str(e).strip().splitlines()[-1][:200]})") from e


def _check_lists_file(path: Path, ondisk: Any, error: ErrorType) -> None:
    """The on-disk lists of an index: ``<index>.ivfdata`` beside it, a regular file (no link) of their size."""
    expected = path.with_suffix(".ivfdata")
    name = Path(str(ondisk.get("filename", ""))) if isinstance(ondisk, dict) else Path("")
    if name.name != expected.name or os.path.realpath(name.parent) != os.path.realpath(path.parent):
        raise error(f"{path}: its inverted lists are named {str(name)[:200]!r}; seqnet reads them only from "
                    f"{expected.name} beside the index")
    if expected.is_symlink():
        raise error(f"{expected} is a symbolic link; seqnet reads a map's lists only from a file in its folder")
    with open_input(expected, "inverted lists", error) as f:
        size = os.fstat(f.fileno()).st_size
    if size < int(ondisk.get("totsize", 0)):
        raise error(f"{expected}: {size} bytes, but the index's lists need {ondisk.get('totsize')}")

