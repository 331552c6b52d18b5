"""MATLAB ``.mat`` files from anywhere (the original seqNet code's ``.db`` structs): scipy's MAT reader, a C
extension, can crash the interpreter on a malformed file and expands compressed elements in full, so a file is
first read through in the sandbox (:mod:`seqnet.security.sandbox`), bounded in memory and time; only a file
that reads there is read here."""

from __future__ import annotations

import os

from ..core.errors import DatasetError
from .arrays import MAX_RATIO
from .inputs import ErrorType, open_input
from .sandbox import run_child


def check_matlab(path: str | os.PathLike[str], what: str = "MAT file", error: ErrorType = DatasetError) -> None:
    """``error`` unless scipy reads ``path`` in the sandbox without crashing, hanging, or needing more memory than
    :data:`seqnet.security.arrays.MAX_RATIO` times the file's size."""
    with open_input(path, what, error) as f:
        size = os.fstat(f.fileno()).st_size
    with run_child("matlab", {"path": os.path.abspath(path)}, f"{what} {path}", (64 << 20) + MAX_RATIO * size,
                   60 + size / 5e6, error):
        pass
