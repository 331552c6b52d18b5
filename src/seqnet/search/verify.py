"""Trust, but verify, the GEMM behind an exact search.

An exact search's distances come from one BLAS/oneDNN product per block, and what that product
computes is not only seqnet's to decide:

- a process-wide ``torch.set_float32_matmul_precision("medium" / "high")`` (common in training
  scripts) lets oneDNN multiply float32 in bfloat16 on CPUs with avx512_bf16 / AMX, and CUDA in TF32:
  distances off by ~1e-4, ranks changed. :func:`full_float32` holds the products of a search at IEEE
  float32 and restores the caller's setting after;
- a kernel may still return a wrong block (seen once under load: one block's distances off by up to
  2.9e-4, see docs/performance.md). :func:`wrong_rows` recomputes every query's best distance in float64
  straight from the two rows (``‖q − r‖``, no norm trick) and names the rows whose GEMM distance is
  further off than float32 rounding allows; :class:`seqnet.search.knn.ExactIndex` searches those again
  in float64 (logged). The check reads one reference row per query: a few percent of the search.
"""

from __future__ import annotations

import contextlib
import logging
import sys
from collections.abc import Iterator

import numpy as np

from ..core.lazy import lazy_module
from ..core.memmaps import take_rows
from ..core.tensors import ArrayLike

torch = lazy_module("torch")
logger = logging.getLogger("seqnet")

# float32 GEMM + norm trick: |error of d²| / (‖q‖² + ‖r‖²) measured ≤ 2.2e-6 at D = 2048 on normalised rows,
# rounding errors growing ~ sqrt(D) eps; a product with bfloat16 inputs is off by ~2^-9 per term.
TOL_EPS = 4.0  # tolerance: TOL_EPS * sqrt(D) * eps(dtype) of ‖q‖² + ‖r‖² (10x the largest float32 error measured)
CHECK_ROWS = 1024  # query rows checked per chunk (bounded memory; small blocks: reused, not page-faulted)


def _knobs() -> list:
    """The per-backend float32 matmul precision settings of this torch (2.9+), else none."""
    found = []
    for name in ("mkldnn", "cuda"):
        matmul = getattr(getattr(torch.backends, name, None), "matmul", None)
        if matmul is not None and hasattr(matmul, "fp32_precision"):
            found.append(matmul)
    return found


@contextlib.contextmanager
def full_float32() -> Iterator[None]:
    """float32 products at IEEE precision inside the block (oneDNN bf16 / TF32 off); the caller's settings
    restored after."""
    old, knobs = torch.get_float32_matmul_precision(), _knobs()
    old_knobs = [k.fp32_precision for k in knobs]
    if old == "highest" and all(v in ("none", "ieee") for v in old_knobs):
        yield  # torch's default (nothing asked for less): no process-wide setting touched, so threads cannot race
        return
    try:
        torch.set_float32_matmul_precision("highest")
        for k in knobs:
            k.fp32_precision = "ieee"
        yield
    finally:
        torch.set_float32_matmul_precision(old)
        for k, v in zip(knobs, old_knobs, strict=True):
            k.fp32_precision = v


def _is_tensor(x: object) -> bool:
    """Whether ``x`` is a torch tensor (without importing torch: a numpy search never loads it)."""
    return "torch" in sys.modules and isinstance(x, sys.modules["torch"].Tensor)


def _as64(x: ArrayLike) -> np.ndarray:
    if _is_tensor(x):
        return x.detach().cpu().double().numpy()
    return np.asarray(x, dtype=np.float64)


def _gather(ref: ArrayLike, idx: np.ndarray) -> np.ndarray:
    """Rows ``idx`` of ``ref`` (numpy, memory map or tensor) as float64 ``[len(idx), D]``."""
    if _is_tensor(ref):
        return _as64(ref[torch.as_tensor(idx, device=ref.device)])
    return _as64(take_rows(ref, idx))


def wrong_rows(query: ArrayLike, ref: ArrayLike, best_vals: np.ndarray, best_idx: np.ndarray, metric: str,
               dtype: str, row_scale: np.ndarray | None = None) -> np.ndarray:
    """Indices of the query rows whose best score ``best_vals [M]`` (distance, or inner product for
    ``"ip"``) of reference ``best_idx [M]`` differs from the float64 recomputation by more than
    :data:`TOL_EPS` ``* sqrt(D) * eps(dtype)`` (``"float32"``/``"float64"``) of ``‖q‖² + ‖r‖²``. A NaN score is
    wrong. ``row_scale [N]``: the reference rows searched were ``ref[i] * row_scale[i]``."""
    tol = TOL_EPS * np.sqrt(max(1, query.shape[1])) * float(np.finfo(dtype).eps)
    bad = []
    for s in range(0, len(best_idx), CHECK_ROWS):
        q = _as64(query[s : s + CHECK_ROWS])
        r = _gather(ref, best_idx[s : s + CHECK_ROWS])
        if row_scale is not None:
            r *= np.asarray(row_scale, np.float64)[best_idx[s : s + CHECK_ROWS], None]
        got = best_vals[s : s + CHECK_ROWS].astype(np.float64)
        scale = np.einsum("ij,ij->i", q, q) + np.einsum("ij,ij->i", r, r)
        if metric == "ip":
            err = np.abs(got - np.einsum("ij,ij->i", q, r))
        else:
            diff = q - r
            err = np.abs(got * got - np.einsum("ij,ij->i", diff, diff))
        bad.append(s + np.flatnonzero(~(err <= tol * scale + np.finfo(np.float64).tiny)))
    return np.concatenate(bad) if bad else np.zeros(0, np.int64)
