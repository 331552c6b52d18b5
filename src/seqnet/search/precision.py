"""Precisions of the searches: the names users give (``--precision``), their torch dtypes, and the dtype a
computation runs in."""

from __future__ import annotations

from ..core.errors import ConfigError
from ..core.lazy import lazy_module
from ..core.tensors import ArrayLike

torch = lazy_module("torch")

PRECISIONS = ("float32", "float16", "bfloat16")  # names of torch dtypes: precision_dtype(name)
HALF = ("float16", "bfloat16")  # read and multiplied in half precision, accumulated and finished in float32


def precision_dtype(name: str) -> torch.dtype:
    """The torch dtype of a :data:`PRECISIONS` name."""
    if name not in PRECISIONS:
        raise ConfigError(f"precision {name!r} is not one of {', '.join(PRECISIONS)}")
    return getattr(torch, name)


def is_half(dtype: torch.dtype) -> bool:
    """Whether ``dtype`` is one of the :data:`HALF` precisions."""
    return str(dtype).removeprefix("torch.") in HALF


def compute_dtype(*xs: ArrayLike) -> torch.dtype:
    """float64 when any input is float64 (exact tests), else float32 (float16 maps are computed in float32)."""
    return torch.float64 if any(str(x.dtype).endswith("float64") for x in xs) else torch.float32
