"""The matrix-vector product of the online localiser's per-frame work (one query row against a map, a
frame through S_1 or S_L), on the CPU kernel that reads memory fastest.

A frame's step is memory-bound: it reads the models' weights and the map once, so its time is the
bytes over the bandwidth a GEMV kernel reaches. On this project's CPU machine (one thread, float32),
NumPy's OpenBLAS ``sgemv`` reads a row-major ``[14000, 4096]`` map at 1.04x the STREAM-copy floor and
a ``[4096, 4096]`` S_1 weight at 1.17x, where torch's (MKL) reaches 1.47x and 1.49x; on the
``[4096, 20480]`` S_L weight the two are close (1.28x vs 1.18x). So float32 CPU products of one vector
use :data:`GEMV_KERNELS` ``["blas"]``; everything else (other dtypes, CUDA, autograd, batches) stays
``torch.mv``, as do matrices under :data:`BLAS_MIN_BYTES` (there the call's overhead, not the
memory, is the cost: Nordland64's HVPR step, 1.33 ms median with torch against 1.52 with OpenBLAS).
``SEQNET_GEMV=torch`` selects torch's kernel (a machine where it is the faster one).
"""

from __future__ import annotations

import os
from collections.abc import Callable

import numpy as np

from .lazy import lazy_module

torch = lazy_module("torch")


def _torch_mv(m: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    return torch.mv(m, v)


def _blas_mv(m: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    return torch.from_numpy(np.matmul(m.numpy(), v.numpy()))


BLAS_MIN_BYTES = 4 << 20  # smaller matrices: torch.mv (no NumPy round trip)
GEMV_KERNELS: dict[str, Callable[[torch.Tensor, torch.Tensor], torch.Tensor]] = {"torch": _torch_mv,
                                                                                  "blas": _blas_mv}


def kernel_name() -> str:
    """The kernel of float32 CPU products (``SEQNET_GEMV``, default ``blas``)."""
    name = os.environ.get("SEQNET_GEMV", "blas")
    return name if name in GEMV_KERNELS else "blas"


def matvec(m: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """``m [R, C] @ v [C]`` → ``[R]``: float32 CPU tensors of at least :data:`BLAS_MIN_BYTES` (contiguous, no
    gradient) on :func:`kernel_name`'s kernel, anything else on ``torch.mv``."""
    plain = (m.device.type == "cpu" and m.dtype == torch.float32 and v.dtype == torch.float32
             and m.numel() * 4 >= BLAS_MIN_BYTES and m.is_contiguous() and v.is_contiguous()
             and not (torch.is_grad_enabled() and (m.requires_grad or v.requires_grad)))
    return GEMV_KERNELS[kernel_name()](m, v) if plain else torch.mv(m, v)
