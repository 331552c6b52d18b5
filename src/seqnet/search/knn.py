"""Distances and exact k-NN: the norm-trick distance matrix, deterministic top-k, k-NN backends.

Every function works on whole arrays; memory is bounded by processing the query side in blocks
(as faiss ``knn_ground_truth`` does). No per-(query, reference) Python loops. Retrieval functions
return ``(scores, indices)``, best first.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from ..core.config import check_choice, check_int
from ..core.errors import ConfigError
from ..core.utils import ArrayLike, as_tensor, get_device, to_numpy
from .blocks import check_pair_dims, col_blocks, compute_dtype, merge_topk, rows

DEFAULT_BLOCK_BYTES = 512 * 2**20
METRICS = ("l2", "ip")


def as_pair(query: ArrayLike, ref: ArrayLike, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """``query [Nq, D]`` and ``ref [Nr, D]`` as float tensors of one dtype on ``device``; checks D."""
    q = as_tensor(query, device, "query", ndim=2, keep_float64=True)
    r = as_tensor(ref, device, "reference", ndim=2, keep_float64=True)
    if q.shape[1] != r.shape[1]:
        raise ConfigError(f"dimension mismatch: query D={q.shape[1]}, reference D={r.shape[1]}")
    r = r.to(q.dtype)
    for name, x in (("query", q), ("reference", r)):
        if not bool(torch.isfinite(sq_norms(x)).all()):  # NaN / inf, or squared norms that overflow
            raise ConfigError(f"{name} descriptors hold NaN or inf, or values too large for "
                              f"{str(x.dtype).removeprefix('torch.')} distances (hint: L2-normalise them)")
    return q, r


def rows_per_block(row_bytes: int, block_bytes: int | None = None) -> int:
    """How many rows of ``row_bytes`` bytes fit a block of ``block_bytes`` (default 512 MiB); at least 1."""
    budget = DEFAULT_BLOCK_BYTES if block_bytes is None else block_bytes
    return max(1, budget // max(1, row_bytes))


def sq_norms(x: torch.Tensor) -> torch.Tensor:
    """Squared L2 norm of every row of ``x [N, D]``: row-wise dot products, no ``[N, D]`` temporary.

    (Not ``vector_norm(x) ** 2``: the square root and square would lose exactness, e.g. identical
    integer-valued rows would no longer be at distance exactly 0.)
    """
    return torch.einsum("ij,ij->i", x, x)


def finish_distances(d: torch.Tensor, q_sq: torch.Tensor, r_sq: torch.Tensor, squared: bool = False) -> torch.Tensor:
    """In place: turn inner products ``d = q @ r.T`` into (squared) Euclidean distances."""
    torch.add(r_sq, d, alpha=-2.0, out=d)  # ‖r‖² − 2 q·r in one pass
    d.add_(q_sq[:, None]).clamp_min_(0.0)
    return d if squared else d.sqrt_()


def pairwise_distances(q: torch.Tensor, r: torch.Tensor, squared: bool = False) -> torch.Tensor:
    """Euclidean distances ``[B, N]`` between rows of ``q [B, D]`` and ``r [N, D]`` (norm trick).

    ``sqrt(max(‖q‖² + ‖r‖² − 2 q·r, 0))``: one GEMM plus in-place element-wise passes.
    """
    return finish_distances(q @ r.T, sq_norms(q), sq_norms(r), squared)


@torch.no_grad()
def knn_torch(query: ArrayLike, ref: ArrayLike, k: int, metric: str = "l2", device: str | None = None,
              block_bytes: int | None = None, col_block: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Exact k-NN by blocked GEMM over query and reference blocks (GPU when present); see :func:`knn`.

    The reference may be a memory-mapped (or float16) array: only one block of it is in torch
    memory at a time, and each query block keeps a running top-k (:mod:`seqnet.search.blocks`).
    """
    dev = get_device(device)
    nq, nr, _ = check_pair_dims(query, ref)
    dtype = compute_dtype(query, ref)
    k = min(k, nr)
    blocks = col_blocks(nr, col_block)
    width = max(b - a for a, b in blocks) if blocks else 1
    step = rows_per_block(width * (8 if dtype == torch.float64 else 4) * 3, block_bytes)
    vals = torch.zeros((nq, k), dtype=dtype)
    idx = torch.zeros((nq, k), dtype=torch.long)
    cache = rows(ref, 0, nr, dev, dtype) if len(blocks) == 1 else None  # a map that fits one block: read once
    for s in range(0, nq, step):
        qb = rows(query, s, min(nq, s + step), dev, dtype)
        q_sq = sq_norms(qb) if metric == "l2" else None
        best = None
        for c0, c1 in blocks:
            rb = cache if cache is not None else rows(ref, c0, c1, dev, dtype)
            scores = (qb @ rb.T).neg_() if q_sq is None else finish_distances(qb @ rb.T, q_sq, sq_norms(rb))
            best = merge_topk(best, scores, torch.arange(c0, c1, device=dev), k)
        if best is not None:
            v, i = best
            vals[s : s + len(qb)], idx[s : s + len(qb)] = (-v if metric == "ip" else v).cpu(), i.cpu()
    return to_numpy(vals), to_numpy(idx)


def knn_faiss(query: ArrayLike, ref: ArrayLike, k: int, metric: str = "l2", device: str | None = None,
              block_bytes: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Exact k-NN with a FAISS flat index (IndexFlatL2 / IndexFlatIP, CPU); see :func:`knn`."""
    import faiss

    q, r = (t.numpy() for t in as_pair(query, ref, torch.device("cpu")))
    k = min(k, r.shape[0])
    if k == 0 or q.shape[0] == 0:
        return np.zeros((q.shape[0], k), np.float32), np.zeros((q.shape[0], k), np.int64)
    index = faiss.IndexFlatIP(r.shape[1]) if metric == "ip" else faiss.IndexFlatL2(r.shape[1])
    index.add(np.ascontiguousarray(r, dtype=np.float32))
    dist, idx = index.search(np.ascontiguousarray(q, dtype=np.float32), k)
    if metric == "l2":
        dist = np.sqrt(np.maximum(dist, 0.0))
    return dist, idx.astype(np.int64)


KNN_BACKENDS: dict[str, Callable[..., tuple[np.ndarray, np.ndarray]]] = {"torch": knn_torch, "faiss": knn_faiss}


def knn(query: ArrayLike, ref: ArrayLike, k: int, backend: str = "torch", metric: str = "l2",
        device: str | None = None, block_bytes: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Exact k nearest references of each query.

    Args:
        query: ``[Nq, D]``; ref: ``[Nr, D]``.
        k: neighbours per query (capped at Nr).
        backend: a key of :data:`KNN_BACKENDS`: ``"torch"`` (blocked GEMM, GPU when present) or
            ``"faiss"`` (flat index).
        metric: ``"l2"`` (ascending Euclidean distance) or ``"ip"`` (descending inner product).
        device: torch device (torch backend).
        block_bytes: memory budget of one block of distances (torch backend; default 512 MiB).

    Returns:
        ``(scores [Nq, k], indices [Nq, k])`` as numpy, best first.
    """
    check_choice("metric", metric, METRICS)
    k = check_int("k", k, 1)
    fn = KNN_BACKENDS[check_choice("k-NN backend", backend, KNN_BACKENDS)]
    return fn(query, ref, k, metric, device, block_bytes)
