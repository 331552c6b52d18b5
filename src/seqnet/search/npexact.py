"""Exact k-NN in numpy (its BLAS), without torch: :class:`NumpyExactIndex`.

The model-free evaluation of descriptor files (``seqnet eval --method single`` and the other k-NN methods
without a model, :mod:`seqnet.reference.plain`) searches with it, so that scoring descriptors never loads
torch. It gives the answers of :class:`seqnet.search.knn.ExactIndex` (the same blocks, the same norm-trick
distances ``sqrt(max(‖q‖² + ‖r‖² − 2 q·r, 0))`` finished in the same order, the same ranking: lowest value,
then lowest column) up to the rounding of the two BLAS libraries' products, and keeps its guards: inputs
whose squared norms are not finite are refused, the products are float32 (float64 when an input is), and
every query's best score is checked against a float64 recomputation (:func:`seqnet.search.verify.wrong_rows`);
when one is off by more than float32 rounding allows, the whole search runs again in float64 (logged).
Memory is bounded: a query block times a reference block of distances, at most ``block_bytes``
(:data:`seqnet.core.memory.BLOCK_BYTES`), the running top-k
(:func:`seqnet.search.nptopk.merge_distances`: the root taken only on candidates).
"""

from __future__ import annotations

import logging

import numpy as np

from ..core.errors import ConfigError
from ..core.memmaps import read_rows
from ..core.memory import BLOCK_BYTES
from .blocks import FINITE_HINT, col_blocks
from .nptopk import merge_distances, merge_smallest
from .verify import wrong_rows

logger = logging.getLogger("seqnet")

NOT_FINITE = ("the distances are not finite: the {what} descriptors hold NaN or inf, or values too large for {dtype} "
              f"({FINITE_HINT})")


def array_shape(x: np.ndarray, name: str) -> tuple[int, int]:
    """``(N, D)`` of a 2-D numeric numpy array (a memory map is not read)."""
    if not isinstance(x, np.ndarray):
        raise ConfigError(f"{name} must be a numpy array, got {type(x).__name__}")
    if x.ndim != 2 or x.dtype.kind not in "fiub":
        raise ConfigError(f"{name} must be a [N, D] matrix of numbers, got shape {x.shape}, dtype {x.dtype}")
    return int(x.shape[0]), int(x.shape[1])


def sq_norms(x: np.ndarray) -> np.ndarray:
    """``[N]`` squared L2 norms of the rows of ``x [N, D]`` (row-wise dot products, no ``[N, D]`` temporary)."""
    return np.einsum("ij,ij->i", x, x)


class NumpyExactIndex:
    """Exact k-NN over ``ref [N, D]`` (numpy array or memory map), streamed in column blocks (see the module).

    ``row_scale [N]``: the rows searched are ``ref[i] * row_scale[i]`` (the L2-normalised rows of a descriptor
    file, searched without a normalised copy: each block's products scaled by column), in ``dtype`` (default:
    float64 when the query or the reference is float64, else float32). The reference's squared norms are
    computed once per dtype and checked finite on first use."""

    def __init__(self, ref: np.ndarray, block_bytes: int | None = None, row_scale: np.ndarray | None = None,
                 dtype: np.dtype | str | None = None) -> None:
        self.ref, self.block_bytes, self.row_scale = ref, block_bytes or BLOCK_BYTES, row_scale
        self.n, self.dim = array_shape(ref, "reference")
        if row_scale is not None and np.shape(row_scale) != (self.n,):
            raise ConfigError(f"row_scale must be [{self.n}], got shape {np.shape(row_scale)}")
        self.blocks = col_blocks(self.n, None, self.dim * ref.dtype.itemsize)
        self.fixed = None if dtype is None else np.dtype(dtype)
        self._norms: dict[np.dtype, np.ndarray] = {}

    def dtype(self, query: np.ndarray) -> np.dtype:
        """The dtype given, else float64 when the query or the reference is float64 (exact tests), else float32."""
        if self.fixed is not None:
            return self.fixed
        return np.dtype(np.float64 if np.float64 in (query.dtype, self.ref.dtype) else np.float32)

    def scale(self, c0: int, c1: int, dtype: np.dtype) -> np.ndarray | None:
        """``row_scale[c0:c1]`` in ``dtype`` (None without one)."""
        return None if self.row_scale is None else np.asarray(self.row_scale[c0:c1], dtype=dtype)

    def block(self, c0: int, c1: int, dtype: np.dtype) -> np.ndarray:
        """Reference rows ``c0:c1`` as ``dtype`` (a view when they are already; a streamed map's pages released)."""
        return np.asarray(read_rows(self.ref, c0, c1), dtype=dtype)

    def norms(self, dtype: np.dtype) -> np.ndarray:
        """``[N]`` squared norms of the reference rows in ``dtype`` (made and checked once)."""
        if dtype not in self._norms:
            whole = np.concatenate([sq_norms(self.block(a, b, dtype)) for a, b in self.blocks] or [np.zeros(0, dtype)])
            if self.row_scale is not None:
                whole *= np.square(self.scale(0, self.n, dtype))
            if not np.isfinite(whole * 4).all():
                raise ConfigError(NOT_FINITE.format(what="reference", dtype=dtype.name))
            self._norms[dtype] = whole
        return self._norms[dtype]

    def search(self, query: np.ndarray, k: int, metric: str = "l2") -> tuple[np.ndarray, np.ndarray]:
        """``(scores [M, k], indices [M, k])`` of ``query [M, D]``, best first (``"l2"``: ascending distances;
        ``"ip"``: descending inner products), ties by the lower index; ``k`` capped at N. Checked as the module
        says."""
        nq, dq = array_shape(query, "query")
        if dq != self.dim:
            raise ConfigError(f"dimension mismatch: query D={dq}, reference D={self.dim}")
        dtype, k = self.dtype(query), min(int(k), self.n)
        vals, idx = self._search(query, k, metric, dtype)
        if k == 0 or nq == 0:
            return vals, idx
        bad = wrong_rows(query, self.ref, vals[:, 0], idx[:, 0], metric, dtype.name, self.row_scale)
        if len(bad):  # the product is not to be trusted on this search: all of it again, in float64
            logger.warning("exact search: %d of %d query rows had a best %s score off by more than %s rounding "
                           "(a faulty GEMM kernel); the search is run again in float64", len(bad), nq, metric,
                           dtype.name)
            v64, idx = self._search(query, k, metric, np.dtype(np.float64))
            vals = v64.astype(vals.dtype)
        return vals, idx

    def _search(self, query: np.ndarray, k: int, metric: str, dtype: np.dtype) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`search` in ``dtype``, unchecked: query blocks against every reference block, a running top-k."""
        nq = len(query)
        if k == 0 or nq == 0:
            return np.zeros((nq, k), dtype), np.zeros((nq, k), np.int64)
        width = max(b - a for a, b in self.blocks)
        step = max(1, self.block_bytes // ((2 * width + self.dim) * dtype.itemsize))
        step = -(-nq // -(-nq // step))  # query blocks of equal size (a thin last block multiplies slowly)
        norms, out_v, out_i = self.norms(dtype), [], []
        for s in range(0, nq, step):
            qb = np.asarray(read_rows(query, s, min(nq, s + step)), dtype=dtype)
            q_sq = sq_norms(qb)
            if not np.isfinite(q_sq * 4).all():
                raise ConfigError(NOT_FINITE.format(what="query", dtype=dtype.name))
            best = None
            for c0, c1 in self.blocks:
                d = qb @ self.block(c0, c1, dtype).T
                if metric == "ip":
                    if self.row_scale is not None:
                        d *= self.scale(c0, c1, dtype)
                    best = merge_smallest(best, np.negative(d, out=d), c0, k)
                    continue
                # ‖r‖² − 2 q·r (the scale and −2 in one exact product), ‖q‖² and the root only on candidates
                scale = self.scale(c0, c1, dtype)
                d *= dtype.type(-2.0) if scale is None else scale * dtype.type(-2.0)
                d += norms[c0:c1]
                best = merge_distances(best, d, q_sq, c0, k)
            out_v.append(best[0])
            out_i.append(best[1])
        vals, idx = np.concatenate(out_v), np.concatenate(out_i)
        return (-vals if metric == "ip" else vals), idx
