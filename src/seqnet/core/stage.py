"""What a stage returns: :class:`Written`, the main file it wrote and what it wrote there."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any


class Written(os.PathLike):
    """What a stage returns: the main file it wrote (``path``; the object is path-like) and what it wrote
    there (``data``), so a caller — the CLI — prints the result without reading the file back."""

    def __init__(self, path: str | Path, data: Any) -> None:
        self.path, self.data = Path(path), data

    def __fspath__(self) -> str:
        return str(self.path)

    def __getattr__(self, name: str) -> Any:  # the Path API (read_text, parent, suffix, ...) of ``path``
        if name in ("path", "data"):
            raise AttributeError(name)
        return getattr(self.path, name)

    def __str__(self) -> str:
        return str(self.path)

    def __repr__(self) -> str:
        return f"Written({str(self.path)!r})"

    def __eq__(self, other: object) -> bool:
        return self.path == (other.path if isinstance(other, Written) else other)

    def __hash__(self) -> int:
        return hash(self.path)
