"""Whole-map SeqMatch fused in cache-sized tiles: the frame distances and their banded sums.

``M[a, b] = Σ_{t<L} d[a+t, b+c_t]`` with ``d`` the frame-distance matrix and ``c_t = t`` (or
``L−1−t`` reversed): each score is a sum along a diagonal band of ``d``. The map is cut into tiles
of query windows × reference windows. A tile's distance rows live in one small buffer: one GEMM
(the only pass over D) adds ``−2 q·r`` to ``‖q‖² + ‖r‖²`` written there first, a clamp and a square
root finish the distances while the buffer is still in cache, and L shifted adds sum the L
diagonals of the buffer straight into the tile of the result. Nothing passes over the whole
``[Nq, Nr]`` matrix after the GEMM: the result is written once, tile by tile.

Consecutive tiles of a column (query windows ``a0..a1``, then ``a1..``) share ``L − 1`` frames: their
distance rows are carried to the front of the buffer, not computed again. Tiles of different
columns overlap by ``L − 1`` reference frames (recomputed: a column is at least 4,096 windows wide
unless the budget is tiny).
"""

from __future__ import annotations

from ..core.lazy import lazy_module
from ..core.memory import BLOCK_BYTES
from ..search.knn import sq_norms

torch = lazy_module("torch")

TILE_BYTES = BLOCK_BYTES // 4
"""A CPU tile's distance buffer (16 MiB): half the 32 MiB L3 of the 2-core machine the figures of
docs/performance.md come from, so the finishing passes and the sums read the buffer from cache."""
MIN_ROWS = 1024
"""Query frames per tile's GEMM before a tile is made narrower: on that machine a GEMM of 1,024 query
rows against 3,000 reference rows runs as fast per product as one of 3,000 (512 rows: ~10% slower)."""


def tile_budget(device: torch.device, tile_bytes: int | None, block_bytes: int | None) -> int:
    """Bytes of one tile's buffer: ``tile_bytes``, else :data:`TILE_BYTES` on the CPU and
    :data:`~seqnet.core.memory.BLOCK_BYTES` elsewhere; at most ``block_bytes`` when given."""
    budget = tile_bytes if tile_bytes is not None else (TILE_BYTES if device.type == "cpu" else BLOCK_BYTES)
    return max(1, budget if block_bytes is None else min(budget, block_bytes))


def tile_shape(na: int, nb: int, halo: int, itemsize: int, budget: int) -> tuple[int, int]:
    """``(rows, width)`` windows per tile: the whole width when :data:`MIN_ROWS` rows of it fit
    ``budget`` bytes (with the ``halo = L − 1`` extra frames of each side), then as many rows as fit,
    balanced over the tiles of a column."""
    elems = max(1, budget // max(1, itemsize))
    least = min(na, MIN_ROWS)
    width = nb if (least + halo) * (nb + halo) <= elems else max(1, min(nb, elems // (least + halo) - halo))
    rows = max(1, min(na, elems // (width + halo) - halo))
    tiles = -(-na // rows)
    return -(-na // tiles), width


def banded_map(q: torch.Tensor, r: torch.Tensor, seq_len: int, reverse: bool = False, budget: int = TILE_BYTES,
               norms: tuple[torch.Tensor, torch.Tensor] | None = None) -> torch.Tensor:
    """SeqMatch scores ``[Nq−L+1, Nr−L+1]`` of every window pair of ``q [Nq, D]`` and ``r [Nr, D]``
    (one dtype and device), in tiles of at most ``budget`` bytes of distances.

    ``norms``: the squared row norms ``(‖q‖² [Nq], ‖r‖² [Nr])`` when already known.
    """
    halo = seq_len - 1
    na, nb = q.shape[0] - halo, r.shape[0] - halo
    q_sq, r_sq = norms if norms is not None else (sq_norms(q), sq_norms(r))
    rows, width = tile_shape(na, nb, halo, q.element_size(), budget)
    out = torch.empty((na, nb), dtype=q.dtype, device=q.device)
    buf = torch.empty((rows + halo) * (width + halo), dtype=q.dtype, device=q.device)
    for c0 in range(0, nb, width):
        c1 = min(nb, c0 + width)
        _column(q, q_sq, r[c0 : c1 + halo], r_sq[c0 : c1 + halo], seq_len, reverse, rows, buf, out[:, c0:c1])
    return out


def _column(q: torch.Tensor, q_sq: torch.Tensor, r: torch.Tensor, r_sq: torch.Tensor, seq_len: int, reverse: bool,
            rows: int, buf: torch.Tensor, out: torch.Tensor) -> None:
    """Fill ``out [Nq−L+1, w]`` (the windows of reference frames ``r [w+L−1, D]``), ``rows`` query
    windows at a time; each tile's buffer starts with the previous tile's last ``L − 1`` distance rows."""
    halo, w = seq_len - 1, r.shape[0]
    cols = [(halo - t) if reverse else t for t in range(seq_len)]  # reference shift of frame t
    done = 0  # query frames whose distance rows are in the buffer (the last ``halo`` of them carried)
    prev = None
    for a0 in range(0, out.shape[0], rows):
        a1 = min(out.shape[0], a0 + rows)
        d = buf[: (a1 - a0 + halo) * w].view(a1 - a0 + halo, w)
        keep = done - a0
        if keep:  # frames a0 .. done: the rows at the end of the previous tile (clone if the two overlap)
            tail = prev[prev.shape[0] - keep :]
            d[:keep].copy_(tail.clone() if prev.shape[0] < 2 * keep else tail)
        distances(d[keep:], q[done : a1 + halo], q_sq[done : a1 + halo], r, r_sq)
        shifted_sum(d, 0, a1 - a0, cols, w - halo, out[a0:a1])
        done, prev = a1 + halo, d


def distances(d: torch.Tensor, q: torch.Tensor, q_sq: torch.Tensor, r: torch.Tensor, r_sq: torch.Tensor) -> None:
    """In place: ``d [n, w] = sqrt(max(‖q‖² + ‖r‖² − 2 q·r, 0))`` (the norms written first, the GEMM adds to them)."""
    torch.add(q_sq[:, None], r_sq[None, :], out=d)
    d.addmm_(q, r.T, alpha=-2.0)
    d.clamp_min_(0.0).sqrt_()


def shifted_sum(dist: torch.Tensor, s: int, e: int, cols: list[int], nb: int, out: torch.Tensor) -> torch.Tensor:
    """``out[i - s, b] = Σ_t dist[i + t, b + cols[t]]`` for rows ``i in [s, e)``: the L shifted adds."""
    if len(cols) == 1:
        return out.copy_(dist[s:e, cols[0] : cols[0] + nb])
    torch.add(dist[s:e, cols[0] : cols[0] + nb], dist[s + 1 : e + 1, cols[1] : cols[1] + nb], out=out)
    for t in range(2, len(cols)):
        out.add_(dist[s + t : e + t, cols[t] : cols[t] + nb])
    return out
