"""The matrix-vector product of the online localiser's per-frame work (one query row against a map, a
frame through S_1 or S_L), on the CPU kernel that reads memory fastest *on this machine*.

A frame's step is memory-bound: it reads the models' weights and the map once, so its time is the
bytes over the bandwidth a GEMV kernel reaches, and which kernel reaches it depends on the CPU and
the dtype. Measured, one thread, ``[14000, 4096]`` map (``docs/scale.md``):

- an AVX2-class machine (2026-12-01): float32 NumPy's OpenBLAS ``sgemv`` 1.04x the STREAM-copy
  floor against torch's ``mv`` 1.47x; float16 ``mv`` fast, bfloat16 ``mv`` 3-5x the floor;
- an AVX-512 / AMX machine (2026-12-02): float32 OpenBLAS 6.2 ms against ``mv`` 11.7 ms; bfloat16
  ``mv`` 4.3 ms; float16 ``mv`` 21 ms but ``F.linear`` of one row 12 ms.

No one table is right on both, so :func:`matvec` times the candidate kernels (:data:`GEMV_KERNELS`
that take the dtype) on the first product of each ``(dtype, shape, threads)`` and keeps the fastest
(:func:`kernel_for`; a few products once, logged). Products torch must do (CUDA, autograd,
non-contiguous, matrices under :data:`BLAS_MIN_BYTES`, where the call's overhead and not the memory
is the cost) stay ``torch.mv``. ``SEQNET_GEMV=torch|linear|blas`` forces one kernel where it takes
the dtype (reproducible timings; a machine where tuning is not wanted).
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable

import numpy as np

from .lazy import lazy_module

torch = lazy_module("torch")
logger = logging.getLogger("seqnet")


def _torch_mv(m: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    return torch.mv(m, v)


def _linear_mv(m: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    return torch.nn.functional.linear(v[None], m)[0]


def _blas_mv(m: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    return torch.from_numpy(np.matmul(m.numpy(), v.numpy()))


BLAS_MIN_BYTES = 4 << 20  # smaller matrices: torch.mv (no tuning, no NumPy round trip)
TUNE_REPEATS = 3  # timed products per candidate kernel (after one untimed)
GEMV_KERNELS: dict[str, Callable[[torch.Tensor, torch.Tensor], torch.Tensor]] = {
    "torch": _torch_mv, "linear": _linear_mv, "blas": _blas_mv}
_FLOAT32_ONLY = {"blas"}  # NumPy has no vectorised half-precision GEMV
_CHOSEN: dict[tuple, str] = {}


def candidates(dtype: torch.dtype) -> list[str]:
    """The kernels of :data:`GEMV_KERNELS` that take ``dtype``."""
    return [k for k in GEMV_KERNELS if dtype == torch.float32 or k not in _FLOAT32_ONLY]


def forced_kernel(dtype: torch.dtype) -> str | None:
    """``SEQNET_GEMV`` when it names a kernel that takes ``dtype``, else ``None`` (tune)."""
    name = os.environ.get("SEQNET_GEMV", "")
    return name if name in candidates(dtype) else None


def _seconds(kernel: Callable, m: torch.Tensor, v: torch.Tensor) -> float:
    kernel(m, v)  # untimed: first touch, allocation
    best = float("inf")
    for _ in range(TUNE_REPEATS):
        start = time.perf_counter()
        kernel(m, v)
        best = min(best, time.perf_counter() - start)
    return best


def kernel_for(m: torch.Tensor, v: torch.Tensor) -> str:
    """The kernel for ``m @ v``: the forced one, else the fastest of :func:`candidates` on this
    ``(dtype, shape, threads)``, timed once per process on ``m`` and ``v`` themselves."""
    forced = forced_kernel(m.dtype)
    if forced:
        return forced
    key = (m.dtype, tuple(m.shape), torch.get_num_threads())
    if key not in _CHOSEN:
        times = {name: _seconds(GEMV_KERNELS[name], m, v) for name in candidates(m.dtype)}
        _CHOSEN[key] = min(times, key=times.get)
        logger.debug("gemv %s %s on %d threads: %s (%s)", m.dtype, tuple(m.shape), key[2], _CHOSEN[key],
                     ", ".join(f"{k} {t * 1e3:.2f} ms" for k, t in times.items()))
    return _CHOSEN[key]


def chosen() -> dict[str, str]:
    """The kernels tuned so far in this process, ``"float16 [14000, 4096] x1" -> "linear"`` (benchmarks print it)."""
    return {f"{str(d).removeprefix('torch.')} {list(shape)} x{threads}": k
            for (d, shape, threads), k in _CHOSEN.items()}


def matvec(m: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """``m [R, C] @ v [C]`` → ``[R]``: CPU tensors of at least :data:`BLAS_MIN_BYTES` (contiguous, same dtype,
    no gradient) on :func:`kernel_for`'s kernel, anything else on ``torch.mv``."""
    plain = (m.device.type == "cpu" and v.device.type == "cpu" and m.dtype == v.dtype
             and m.numel() * m.element_size() >= BLAS_MIN_BYTES and m.is_contiguous() and v.is_contiguous()
             and not (torch.is_grad_enabled() and (m.requires_grad or v.requires_grad)))
    return GEMV_KERNELS[kernel_for(m, v)](m, v) if plain else torch.mv(m, v)
