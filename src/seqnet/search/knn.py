"""Distances and exact k-NN: the norm-trick distance matrix, deterministic top-k, k-NN backends.

Every function works on whole arrays; memory is bounded by processing the query side in blocks
(as faiss ``knn_ground_truth`` does). No per-(query, reference) Python loops. Retrieval functions
return ``(scores, indices)``, best first.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator

import numpy as np

from ..core.config import check_choice, check_int
from ..core.devices import get_device
from ..core.errors import ConfigError
from ..core.gemv import matvec
from ..core.lazy import lazy_module, no_grad
from ..core.memmaps import limit, streamed
from ..core.memory import BLOCK_BYTES as MEMORY_BLOCK
from ..core.tensors import ArrayLike, as_tensor
from .blocks import FINITE_HINT, blocked_topk, col_blocks, matrix_shape, rows, topk_smallest
from .precision import compute_dtype, is_half
from .verify import full_float32, wrong_rows

torch = lazy_module("torch")
logger = logging.getLogger("seqnet")

DEFAULT_BLOCK_BYTES = MEMORY_BLOCK
NOT_FINITE = ("the distances are not finite: the {what} descriptors hold NaN or inf, or values too large for {dtype} "
              f"({FINITE_HINT})")
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
                              f"{str(x.dtype).removeprefix('torch.')} distances ({FINITE_HINT})")
    return q, r


def rows_per_block(row_bytes: int, block_bytes: int | None = None) -> int:
    """How many rows of ``row_bytes`` bytes fit a block of ``block_bytes`` (default 64 MiB); at least 1."""
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


def acc(dtype: torch.dtype) -> torch.dtype:
    """The dtype distances are accumulated and finished in: float32 for half-precision inputs."""
    return torch.float32 if is_half(dtype) else dtype


def inner(q: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """``q @ r.T`` ``[M, N]``; one query row (a frame of a stream) as a GEMV on the row-major reference."""
    return matvec(r, q[0])[None] if len(q) == 1 else q @ r.T


class ExactIndex:
    """Exact k-NN over ``ref [N, D]`` (numpy, memory map, float16 or a tensor), streamed in column blocks.

    The one exact search of seqnet: :func:`knn` (torch backend), a dataset's reference and a map's
    stored descriptors all use it. The reference's squared norms are computed once per index and
    dtype, so an index queried many times (a map, the localiser) pays one GEMM per block per query.
    ``precision`` (float16 / bfloat16) reads the reference and multiplies in half precision (half the
    bytes of a memory-bound search), accumulating and finishing the distances in float32.
    ``keep`` holds a reference of at most :data:`seqnet.core.memmaps.RESIDENT_BYTES` (256 MiB) in torch memory
    (a view of a float32 CPU array, else one copy); a larger or spilled one is read block by block
    at every search, its pages released after each (:func:`seqnet.core.memmaps.read_rows`), unless
    ``resident`` (an online localiser searching the same map every frame keeps it whatever its size).
    """

    def __init__(self, ref: ArrayLike, device: str | torch.device | None = None, block_bytes: int | None = None,
                 col_block: int | None = None, keep: bool = True, precision: torch.dtype | None = None,
                 resident: bool = False) -> None:
        self.ref, self.device, self.block_bytes, self.precision = ref, get_device(device), block_bytes, precision
        self.n, self.dim = matrix_shape(ref, "reference")
        itemsize = 8 if str(ref.dtype).endswith("float64") else 4
        self.blocks = col_blocks(self.n, col_block, self.dim * itemsize)
        self.keep = resident or (keep and not streamed(ref) and self.n * self.dim * itemsize <= limit("RESIDENT"))
        self._rows: dict[torch.dtype, torch.Tensor] = {}
        self._norms: dict[torch.dtype, list[torch.Tensor]] = {}
        self._cols: dict[int, torch.Tensor] = {}

    def block(self, c0: int, c1: int, dtype: torch.dtype) -> torch.Tensor:
        """Reference rows ``c0:c1`` as ``dtype`` on the device (the kept copy when there is one)."""
        if not self.keep:
            return rows(self.ref, c0, c1, self.device, dtype)
        if dtype not in self._rows:
            self._rows[dtype] = rows(self.ref, 0, self.n, self.device, dtype)
        return self._rows[dtype][c0:c1]

    def columns(self, j: int) -> torch.Tensor | None:
        """The reference indices ``[c]`` of column block ``j`` (made once; None for a block starting at 0:
        its columns are its own indices)."""
        if self.blocks[j][0] == 0:
            return None
        if j not in self._cols:
            self._cols[j] = torch.arange(*self.blocks[j], device=self.device)
        return self._cols[j]

    def dtype(self, query: ArrayLike) -> torch.dtype:
        """The dtype the reference is read and multiplied in (``precision``, else float32 / float64)."""
        return self.precision or compute_dtype(query, self.ref)

    def norms(self, dtype: torch.dtype) -> list[torch.Tensor]:
        """Squared norms of each reference block (computed and checked finite on first use; float32 for half):
        views of one ``[N]`` tensor (:meth:`all_norms`)."""
        if dtype not in self._norms:
            norms = [sq_norms(self.block(a, b, dtype).to(acc(dtype))) for a, b in self.blocks]
            whole = torch.cat(norms) if norms else torch.zeros(0, device=self.device, dtype=acc(dtype))
            if not bool(torch.isfinite(whole * 4).all()):
                raise ConfigError(NOT_FINITE.format(what="reference", dtype=str(dtype).removeprefix("torch.")))
            self._norms[dtype] = [whole[a:b] for a, b in self.blocks] + [whole]
        return self._norms[dtype][:-1]

    def all_norms(self, dtype: torch.dtype) -> torch.Tensor:
        """``[N]``: the squared norms of every reference row (the blocks of :meth:`norms`, made once)."""
        self.norms(dtype)
        return self._norms[dtype][-1]

    @no_grad
    def distances(self, query: ArrayLike, metric: str = "l2", finite: bool = False) -> torch.Tensor:
        """``[M, N]`` Euclidean distances (``metric="ip"``: negated inner products) of ``query [M, D]`` (a few
        rows: a frame of a stream) to the reference: one product when the reference is kept in memory, else one
        per column block. ``finite``: non-finite query rows are refused (as :meth:`search` does)."""
        dtype = self.dtype(query)
        q = rows(query, 0, len(query), self.device, dtype)
        q_sq = sq_norms(q.to(acc(dtype)))
        if finite and not bool(torch.isfinite(q_sq * 4).all()):
            raise ConfigError(NOT_FINITE.format(what="query", dtype=str(dtype).removeprefix("torch.")))
        blocks = [(0, self.n)] if self.keep else self.blocks
        norms = [self.all_norms(dtype)] if self.keep else self.norms(dtype)
        with full_float32():
            parts = [inner(q, self.block(c0, c1, dtype)).to(acc(dtype)) for c0, c1 in blocks]
        parts = [d.neg_() if metric == "ip" else finish_distances(d, q_sq, n)
                 for d, n in zip(parts, norms, strict=True)]
        return parts[0] if len(parts) == 1 else torch.cat(parts, dim=1)

    @no_grad
    def search(self, query: ArrayLike, k: int, metric: str = "l2") -> tuple[np.ndarray, np.ndarray]:
        """``(scores [M, k], indices [M, k])``, best first, ties by the lower index (see :func:`knn`).

        The products run at IEEE float32 whatever the process's matmul precision, and every query's best
        score is checked against a float64 recomputation (:mod:`seqnet.search.verify`); when a kernel got one
        wrong, the whole search runs again in float64 (logged), so the answer does not depend on the kernel."""
        nq, dq = matrix_shape(query, "query")
        if dq != self.dim:
            raise ConfigError(f"dimension mismatch: query D={dq}, reference D={self.dim}")
        dtype, k = self.dtype(query), min(k, self.n)
        with full_float32():
            vals, idx = self._search(query, nq, k, metric, dtype)
        if is_half(dtype) or k == 0 or nq == 0:
            return vals, idx  # half precision: the caller chose rounding; nothing to check
        bad = wrong_rows(query, self.ref, vals[:, 0], idx[:, 0], metric, str(dtype).removeprefix("torch."))
        if len(bad):  # the kernel is not to be trusted on this search: all of it again, in float64
            logger.warning("exact search: %d of %d query rows had a best %s score off by more than %s rounding "
                           "(a reduced-precision or faulty GEMM kernel); the search is run again in float64",
                           len(bad), nq, metric, str(dtype).removeprefix("torch."))
            v64, idx = ExactIndex(self.ref, self.device, self.block_bytes, keep=False)._search(
                query, nq, k, metric, torch.float64)
            vals = v64.astype(vals.dtype)
        return vals, idx

    def _search(self, query: ArrayLike, nq: int, k: int, metric: str,
                dtype: torch.dtype) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`search` in ``dtype``, unchecked."""
        if self.keep and len(self.blocks) > 1 and nq * self.n * 16 <= (self.block_bytes or DEFAULT_BLOCK_BYTES):
            return self._search_rows(query, k, metric, dtype)  # a few rows against a kept reference: one GEMV
        width = max((b - a for a, b in self.blocks), default=1)
        step = rows_per_block((width * 3 + self.dim) * (8 if dtype == torch.float64 else 4), self.block_bytes)
        norms, finite = self.norms(dtype), []  # the reference's norms are checked once, the query's here

        def row_blocks() -> Iterator[tuple[slice, tuple[torch.Tensor, torch.Tensor]]]:
            for s in range(0, nq, step):
                qb = rows(query, s, min(nq, s + step), self.device, dtype)
                q_sq = sq_norms(qb.to(acc(dtype)))
                finite.append(torch.isfinite(q_sq * 4).all())  # finite norms: every distance is finite
                yield slice(s, min(nq, s + step)), (qb, q_sq)

        def score(ctx: tuple[torch.Tensor, torch.Tensor], j: int) -> tuple[torch.Tensor, torch.Tensor]:
            (qb, q_sq), (c0, c1) = ctx, self.blocks[j]
            d = inner(qb, self.block(c0, c1, dtype)).to(acc(dtype))
            return (d.neg_() if metric == "ip" else finish_distances(d, q_sq, norms[j])), self.columns(j)

        vals, idx = blocked_topk(row_blocks(), range(len(self.blocks)), score, nq, k, acc(dtype), finite=False)
        if finite and not bool(torch.stack(finite).all()):  # one host sync per search
            raise ConfigError(NOT_FINITE.format(what="query", dtype=str(dtype).removeprefix("torch.")))
        return (-vals if metric == "ip" else vals), idx


    def _search_rows(self, query: ArrayLike, k: int, metric: str, dtype: torch.dtype) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`search` of a few query rows (a frame of a stream) whose scores against the whole kept
        reference fit one block: :meth:`distances` (one product), one top-k (the same ranking as the blocks)."""
        vals, idx = topk_smallest(self.distances(query, metric, finite=True), k)
        return (-vals if metric == "ip" else vals).cpu().numpy(), idx.cpu().numpy()


def knn_torch(query: ArrayLike, ref: ArrayLike, k: int, metric: str = "l2", device: str | None = None,
              block_bytes: int | None = None, col_block: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Exact k-NN by blocked GEMM over query and reference blocks (GPU when present); see :func:`knn`.

    The reference may be a memory-mapped (or float16) array: only one block of it is in torch
    memory at a time, and each query block keeps a running top-k (:func:`seqnet.search.blocks.blocked_topk`).
    """
    return ExactIndex(ref, device, block_bytes, col_block).search(query, k, metric)


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
        block_bytes: memory budget of one block of distances (torch backend; default 64 MiB,
            :data:`DEFAULT_BLOCK_BYTES`).

    Returns:
        ``(scores [Nq, k], indices [Nq, k])`` as numpy, best first.
    """
    check_choice("metric", metric, METRICS)
    k = check_int("k", k, 1)
    fn = KNN_BACKENDS[check_choice("k-NN backend", backend, KNN_BACKENDS)]
    return fn(query, ref, k, metric, device, block_bytes)
