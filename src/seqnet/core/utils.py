"""Small shared helpers: the logger, devices and array conversion."""

from __future__ import annotations

import logging
from typing import Union

import numpy as np

from .errors import ConfigError
from .lazy import lazy_module

torch = lazy_module("torch")

logger = logging.getLogger("seqnet")

ArrayLike = Union[np.ndarray, "torch.Tensor"]  # noqa: UP007 - a forward reference: torch loads on first use


def check_device(device: str | torch.device | None) -> None:
    """Validate a device name (:class:`ConfigError` if unknown or absent); the CPU names need no torch import."""
    if device not in (None, "auto", "cpu"):
        get_device(device)


def get_device(device: str | torch.device | None = None) -> torch.device:
    """Return ``device`` or, when None/"auto", CUDA when available else CPU."""
    if device in (None, "auto"):
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if isinstance(device, torch.device):
        return device
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError, ValueError) as err:
        raise ConfigError(f"unknown device {device!r}; use auto, cpu, cuda or cuda:N") from err
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"device {device!r} requested but CUDA is not available; use --device cpu or auto")
    if dev.type == "cuda" and dev.index is not None and dev.index >= torch.cuda.device_count():
        raise ConfigError(f"device {device!r} does not exist ({torch.cuda.device_count()} CUDA device(s))")
    return dev


def as_tensor(
    x: ArrayLike, device: torch.device | str | None = None, name: str = "array", ndim: int | None = None,
    keep_float64: bool = False,
) -> torch.Tensor:
    """``x`` (numpy, possibly memory-mapped or read-only, or torch) as a float tensor on ``device``.

    float32 unless ``keep_float64`` and ``x`` is float64. With ``ndim``, the number of dimensions is
    checked (:class:`ConfigError` naming ``name``). Read-only arrays are copied, not warned about.
    """
    if isinstance(x, torch.Tensor):
        t = x
    else:
        arr = np.asarray(x)
        if arr.dtype.kind not in "fiub":
            raise ConfigError(f"{name} must hold numbers, got dtype {arr.dtype}")
        if not arr.dtype.isnative:
            arr = arr.astype(arr.dtype.newbyteorder("="))
        arr = np.ascontiguousarray(arr)
        t = torch.from_numpy(arr if arr.flags.writeable else arr.copy())
    if not (t.dtype == torch.float32 or (keep_float64 and t.dtype == torch.float64)):
        t = t.float()
    if ndim is not None and t.ndim != ndim:
        shape = "[N, D] matrix" if ndim == 2 else f"{ndim}-D array"
        raise ConfigError(f"{name} must be a {shape}, got shape {tuple(t.shape)}")
    return t.to(device) if device is not None else t


def to_numpy(x: ArrayLike) -> np.ndarray:
    """Return ``x`` as a numpy array (on CPU)."""
    if isinstance(x, torch.Tensor):
        return x.detach().cpu().numpy()
    return np.asarray(x)


def l2_normalize(x: torch.Tensor, dim: int = -1, eps: float = 1e-12) -> torch.Tensor:
    """L2-normalise ``x`` along ``dim`` (zero vectors stay zero).

    Rows are first divided by their largest magnitude, so finite values beyond ``sqrt(float max)``
    (e.g. 1e19 in float32) do not overflow the norm into inf (which would make them zero vectors).
    """
    scale = x.abs().amax(dim=dim, keepdim=True).clamp_min(torch.finfo(x.dtype).tiny if x.is_floating_point() else 1)
    y = x / scale
    return y / y.norm(dim=dim, keepdim=True).clamp_min(eps)
