"""Exact search over a memory-mapped map with the reference norms computed once.

:func:`seqnet.search.knn.knn_torch` recomputes the squared norms of every reference block on every
call, a second pass over the map per query; a map is queried many times, so its norms are
computed once (the same values, :func:`seqnet.search.knn.sq_norms`) and each query block then costs
one GEMM per reference block plus a running top-k (:mod:`seqnet.search.blocks`).
"""

from __future__ import annotations

import numpy as np
import torch

from ..core.utils import ArrayLike, to_numpy
from ..search.blocks import check_pair_dims, col_blocks, compute_dtype, merge_topk, rows
from ..search.knn import finish_distances, rows_per_block, sq_norms


class ExactSearch:
    """Exact L2 k-NN over ``ref [N, D]`` (numpy, memory map, float16 or a tensor), streamed in column blocks."""

    def __init__(self, ref: ArrayLike, device: torch.device, block_bytes: int, col_block: int | None = None) -> None:
        self.ref, self.device, self.block_bytes, self.col_block = ref, device, block_bytes, col_block
        self.dtype = compute_dtype(ref)
        self.blocks = col_blocks(len(ref), col_block)
        self._norms: list[torch.Tensor] | None = None

    def norms(self) -> list[torch.Tensor]:
        """Squared norms of each reference block (computed on first use)."""
        if self._norms is None:
            self._norms = [sq_norms(rows(self.ref, a, b, self.device, self.dtype)) for a, b in self.blocks]
        return self._norms

    @torch.no_grad()
    def __call__(self, query: ArrayLike, k: int) -> tuple[np.ndarray, np.ndarray]:
        """``(distances [M, k], indices [M, k])``, ascending, ties by the lower index (as :func:`knn_torch`)."""
        nq, nr, _ = check_pair_dims(query, self.ref)
        k = min(k, nr)
        width = max(b - a for a, b in self.blocks)
        step = rows_per_block(width * 4 * 3, self.block_bytes)
        vals, idx = torch.zeros((nq, k), dtype=self.dtype), torch.zeros((nq, k), dtype=torch.long)
        norms = self.norms()
        for s in range(0, nq, step):
            qb = rows(query, s, min(nq, s + step), self.device, self.dtype)
            q_sq, best = sq_norms(qb), None
            for (c0, c1), r_sq in zip(self.blocks, norms, strict=True):
                rb = rows(self.ref, c0, c1, self.device, self.dtype)
                scores = finish_distances(qb @ rb.T, q_sq, r_sq)
                best = merge_topk(best, scores, torch.arange(c0, c1, device=self.device), k)
            vals[s : s + len(qb)], idx[s : s + len(qb)] = best[0].cpu(), best[1].cpu()
        return to_numpy(vals), to_numpy(idx)
