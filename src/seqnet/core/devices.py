"""The torch device of a computation: names validated, ``auto`` resolved (CUDA when present, else the CPU)."""

from __future__ import annotations

from .errors import ConfigError
from .lazy import lazy_module

torch = lazy_module("torch")


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
