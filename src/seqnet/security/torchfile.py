"""The one safe loader of torch files (checkpoints, fitted state): tensors and plain data, never code."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import CheckpointError


def _numpy_globals() -> list[Any]:
    """numpy objects allowed in torch files (the original SeqNet code stored numpy scalars)."""
    core = np._core if hasattr(np, "_core") else np.core  # type: ignore[attr-defined]
    out: list[Any] = [np.dtype, *(type(np.dtype(t)) for t in (np.float64, np.float32, np.int64, np.int32, np.bool_))]
    for name in ("scalar", "_reconstruct"):
        fn = getattr(core.multiarray, name)
        out += [fn, (fn, f"numpy.core.multiarray.{name}"), (fn, f"numpy._core.multiarray.{name}")]
    return out + [np.ndarray]


def load_torch_file(path: str | os.PathLike[str], what: str = "checkpoint") -> Any:
    """Read a ``torch.save`` file safely (``weights_only``); :class:`CheckpointError` if missing or unreadable."""
    import torch

    path = Path(path)
    if not path.is_file():
        hint = " (it is a directory)" if path.is_dir() else ""
        raise CheckpointError(f"{what} not found: {path}{hint}")
    try:
        with torch.serialization.safe_globals(_numpy_globals()):
            return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises RuntimeError, UnpicklingError, EOFError, zipfile errors ...
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise CheckpointError(f"cannot read {what} {path}: corrupted or not a torch file ({first[:200]})") from e
