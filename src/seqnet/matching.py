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

DEFAULT_BLOCK_BYTES = 512 * 2**20


def _tensor(x: ArrayLike, device: torch.device, name: str) -> torch.Tensor:
    """``x`` as a float32/float64 ``[N, D]`` tensor on ``device`` (read-only arrays are copied, not warned about)."""
    if isinstance(x, torch.Tensor):
        t = x
    else:
        arr = np.asarray(x)
        if arr.dtype.kind not in "fiub":
            raise ConfigError(f"{name} must hold numbers, got dtype {arr.dtype}")
        arr = np.ascontiguousarray(arr)
        t = torch.from_numpy(arr if arr.flags.writeable else arr.copy())
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


def topk_smallest(scores: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The ``k`` smallest entries of each row of ``scores [B, N]``, ascending.

    Ties are broken deterministically by the lower column index (also at the cut-off); NaN ranks
    like +inf. Returns ``(values [B, k], indices [B, k])``; ``k`` is capped at N.
    """
    k = min(int(k), scores.shape[1])
    if k <= 0 or scores.shape[0] == 0:
        empty = scores.new_zeros((scores.shape[0], max(k, 0)))
        return empty, empty.long()
    key = scores.masked_fill(torch.isnan(scores), float("inf")) if scores.is_floating_point() else scores
    kth = torch.topk(key, k, dim=1, largest=False, sorted=True).values[:, -1:]
    less = key < kth
    ties = key == kth
    need = k - less.sum(1, keepdim=True)
    keep = less | (ties & (ties.cumsum(1) <= need))
    idx = keep.nonzero()[:, 1].reshape(scores.shape[0], k)  # ascending column order
    order = torch.sort(key.gather(1, idx), dim=1, stable=True).indices
    idx = idx.gather(1, order)
    return scores.gather(1, idx), idx


@torch.no_grad()
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
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
        raise ConfigError(f"k must be an integer >= 1, got {k!r}")
    if backend == "faiss":
        return _knn_faiss(to_numpy(query), to_numpy(ref), k, metric)
    if backend != "torch":
        raise ConfigError(f"k-NN backend {backend!r} is not one of ('torch', 'faiss')")
    dev = get_device(device)
    q, r = _tensor(query, dev, "query"), _tensor(ref, dev, "reference")
    r = _check_pair(q, r)
    rows = _rows_per_block(r.shape[0] * q.element_size() * 3, block_bytes)
    r_sq = sq_norms(r) if metric == "l2" else None
    vals, idx = [], []
    for s in range(0, q.shape[0], rows):
        qb = q[s : s + rows]
        scores = (qb @ r.T).neg_() if r_sq is None else finish_distances(qb @ r.T, sq_norms(qb), r_sq)
        v, i = topk_smallest(scores, k)
        vals.append(-v if metric == "ip" else v)
        idx.append(i)
    if not vals:
        k = min(k, r.shape[0])
        return np.zeros((0, k), np.float32), np.zeros((0, k), np.int64)
    return to_numpy(torch.cat(vals)), to_numpy(torch.cat(idx))


def _knn_faiss(q: np.ndarray, r: np.ndarray, k: int, metric: str) -> tuple[np.ndarray, np.ndarray]:
    import faiss

    for name, a in (("query", q), ("reference", r)):
        if a.ndim != 2:
            raise ConfigError(f"{name} must be a [N, D] matrix, got shape {tuple(a.shape)}")
    if q.shape[1] != r.shape[1]:
        raise ConfigError(f"dimension mismatch: query D={q.shape[1]}, reference D={r.shape[1]}")
    k = min(k, r.shape[0])
    if k == 0 or q.shape[0] == 0:
        return np.zeros((q.shape[0], k), np.float32), np.zeros((q.shape[0], k), np.int64)
    index = faiss.IndexFlatIP(r.shape[1]) if metric == "ip" else faiss.IndexFlatL2(r.shape[1])
    index.add(np.ascontiguousarray(r, dtype=np.float32))
    dist, idx = index.search(np.ascontiguousarray(q, dtype=np.float32), k)
    if metric == "l2":
        dist = np.sqrt(np.maximum(dist, 0.0))
    return dist, idx.astype(np.int64)
