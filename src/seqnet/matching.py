"""Matching: distance matrices, exact k-NN (torch blocks or FAISS), SeqMatch and HVPR.

Every function works on whole arrays; memory is bounded by processing the query side in blocks
(as faiss ``knn_ground_truth`` does). No per-(query, reference) Python loops.

SeqMatch (paper eq.): ``M[a, b] = Σ_{t=0}^{L-1} ‖query[a+t] − ref[b+t]‖₂`` — one distance matrix
(a GEMM with the norm trick ``‖q‖² + ‖r‖² − 2 q·r``) plus L shifted (diagonal) sums.
"""

from __future__ import annotations

import numpy as np
import torch

from .errors import ConfigError
from .utils import ArrayLike, get_device, to_numpy
from .windows import check_seq_len

DEFAULT_BLOCK_BYTES = 512 * 2**20


def _tensor(x: ArrayLike, device: torch.device, name: str) -> torch.Tensor:
    t = x if isinstance(x, torch.Tensor) else torch.from_numpy(np.ascontiguousarray(x))
    if not t.is_floating_point():
        t = t.float()
    if t.dtype not in (torch.float32, torch.float64):
        t = t.float()
    if t.ndim != 2:
        raise ConfigError(f"{name} must be a [N, D] matrix, got shape {tuple(t.shape)}")
    return t.to(device)


def _check_pair(q: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    if q.shape[1] != r.shape[1]:
        raise ConfigError(f"dimension mismatch: query D={q.shape[1]}, reference D={r.shape[1]}")
    return r.to(q.dtype)


def _rows_per_block(row_cost: int, block_bytes: int | None) -> int:
    budget = DEFAULT_BLOCK_BYTES if block_bytes is None else block_bytes
    return max(1, budget // max(1, row_cost))


def pairwise_distances(q: torch.Tensor, r: torch.Tensor, squared: bool = False) -> torch.Tensor:
    """Euclidean distances ``[B, N]`` between rows of ``q [B, D]`` and ``r [N, D]`` (norm trick)."""
    d = torch.addmm((r * r).sum(1)[None, :], q, r.T, beta=1.0, alpha=-2.0)
    d.add_((q * q).sum(1)[:, None]).clamp_min_(0.0)
    return d if squared else d.sqrt_()


def topk_smallest(scores: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The ``k`` smallest entries of each row of ``scores [B, N]``, ascending.

    Ties are broken deterministically by the lower column index (also at the cut-off).
    Returns ``(values [B, k], indices [B, k])``; ``k`` is capped at N.
    """
    k = min(int(k), scores.shape[1])
    if k <= 0 or scores.shape[0] == 0:
        empty = scores.new_zeros((scores.shape[0], max(k, 0)))
        return empty, empty.long()
    kth = torch.topk(scores, k, dim=1, largest=False, sorted=True).values[:, -1:]
    less = scores < kth
    ties = scores == kth
    need = k - less.sum(1, keepdim=True)
    keep = less | (ties & (ties.cumsum(1) <= need))
    idx = keep.nonzero()[:, 1].reshape(scores.shape[0], k)  # ascending column order
    vals = scores.gather(1, idx)
    order = torch.sort(vals, dim=1, stable=True).indices
    return vals.gather(1, order), idx.gather(1, order)


def knn(
    query: ArrayLike,
    ref: ArrayLike,
    k: int,
    backend: str = "torch",
    metric: str = "l2",
    device: str | None = None,
    block_bytes: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Exact k nearest references of each query.

    Args:
        query: ``[Nq, D]``; ref: ``[Nr, D]``.
        k: neighbours per query (capped at Nr).
        backend: ``"torch"`` (blocked GEMM, GPU when present) or ``"faiss"`` (IndexFlatL2/IP).
        metric: ``"l2"`` (ascending Euclidean distance) or ``"ip"`` (descending inner product).

    Returns:
        ``(scores [Nq, k], indices [Nq, k])`` as numpy, best first.
    """
    if metric not in ("l2", "ip"):
        raise ConfigError(f"metric {metric!r} is not one of ('l2', 'ip')")
    if backend == "faiss":
        return _knn_faiss(to_numpy(query), to_numpy(ref), k, metric)
    if backend != "torch":
        raise ConfigError(f"k-NN backend {backend!r} is not one of ('torch', 'faiss')")
    dev = get_device(device)
    q, r = _tensor(query, dev, "query"), _tensor(ref, dev, "reference")
    r = _check_pair(q, r)
    rows = _rows_per_block(r.shape[0] * q.element_size() * 3, block_bytes)
    vals, idx = [], []
    for s in range(0, q.shape[0], rows):
        qb = q[s : s + rows]
        scores = -(qb @ r.T) if metric == "ip" else pairwise_distances(qb, r)
        v, i = topk_smallest(scores, k)
        vals.append(-v if metric == "ip" else v)
        idx.append(i)
    if not vals:
        k = min(k, r.shape[0])
        return np.zeros((0, k), np.float32), np.zeros((0, k), np.int64)
    return to_numpy(torch.cat(vals)), to_numpy(torch.cat(idx))


def _knn_faiss(q: np.ndarray, r: np.ndarray, k: int, metric: str) -> tuple[np.ndarray, np.ndarray]:
    import faiss

    if q.shape[1] != r.shape[1]:
        raise ConfigError(f"dimension mismatch: query D={q.shape[1]}, reference D={r.shape[1]}")
    k = min(k, r.shape[0])
    index = faiss.IndexFlatIP(r.shape[1]) if metric == "ip" else faiss.IndexFlatL2(r.shape[1])
    index.add(np.ascontiguousarray(r, dtype=np.float32))
    dist, idx = index.search(np.ascontiguousarray(q, dtype=np.float32), k)
    if metric == "l2":
        dist = np.sqrt(np.maximum(dist, 0.0))
    return dist, idx.astype(np.int64)
