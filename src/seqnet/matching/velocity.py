"""Velocity-robust SeqMatch (SeqSLAM-style trajectory search), whole map or given window pairs.

A query window of L frames starts at ``a``; a reference item is the window that starts at ``b``.
Its *pivot* is step ``p`` of the window (``anchor``: ``"start"`` p = 0, ``"centre"`` p = L // 2,
``"end"`` p = L − 1): fixed-speed SeqMatch pairs query frame ``a + p`` with reference frame
``b + p``, and every trajectory passes through that pair. With slope ``v`` (reference frames per
query frame) the reference frame of step t is

* forward: ``b + p + R(v · (t − p))``;
* reverse (the reference walked backwards, like ``seqmatch-rev``): ``b + L − 1 − p − R(v · (t − p))``,

where ``R(x) = sign(x) · floor(|x| + 1/2)`` rounds half away from zero (trajectories are symmetric
about the pivot). The score is ``min_v Σ_t ‖q[a + t] − r[traj_v(t)]‖₂``; a trajectory that leaves
the reference traverse is invalid (``inf``), never clamped. Slopes ``v ≤ 1`` stay inside the
window ``b .. b + L − 1``, so with ``1`` in the set every item has a finite score, and
``velocities=(1,)`` is fixed-speed SeqMatch exactly. With ``anchor="centre"`` and the centred
windows of :mod:`seqnet.eval.evaluate`, the query item's frame is aligned with the reference item's
frame, so Recall@K compares the positions of the frames that were matched.

Whole map: per block of query windows one distance matrix (GEMM + norm trick), then per distinct
trajectory L shifted column slices summed (:func:`seqnet.matching.banded.shifted_sum`) and a running
minimum; memory is bounded by blocks of about three ``[rows, Nr]`` buffers.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterator, Sequence

import numpy as np

from ..core.config import check_choice, check_float, check_int
from ..core.devices import get_device
from ..core.errors import ConfigError
from ..core.lazy import lazy_module, no_grad
from ..core.progress import progress
from ..core.tensors import ArrayLike, to_numpy
from ..search.blocks import blocked_topk
from ..search.knn import as_pair, rows_per_block, sq_norms
from ..sequence.windows import check_seq_len
from .banded import distances, shifted_sum
from .seqmatch import check_starts

torch = lazy_module("torch")

DEFAULT_VELOCITIES = (0.5, 0.75, 1.0, 1.5, 2.0)
ANCHORS = ("start", "centre", "end")
BlockFn = Callable[["torch.Tensor", int, int], "torch.Tensor"]  # (dist [n+L-1, Nr], first window, n) -> [n, W]


def check_velocities(velocities: Sequence[float]) -> tuple[float, ...]:
    """A non-empty sequence of finite slopes ``> 0``, sorted and without duplicates."""
    if isinstance(velocities, (str, bytes)) or not isinstance(velocities, (Sequence, np.ndarray)) \
            or len(velocities) == 0:
        raise ConfigError(f"velocities must be a non-empty list of numbers > 0, got {velocities!r}")
    return tuple(sorted({check_float("velocity", v, 0.0, strict=True) for v in velocities}))


def pivot_step(anchor: str, seq_len: int) -> int:
    """The step p of the window anchored to the item: 0, L // 2 or L − 1 (see the module docstring)."""
    check_choice("anchor", anchor, ANCHORS)
    return {"start": 0, "centre": seq_len // 2, "end": seq_len - 1}[anchor]


def round_half_away(x: float) -> int:
    """``sign(x) · floor(|x| + 1/2)``."""
    return int(math.copysign(math.floor(abs(x) + 0.5), x))


def trajectories(velocities: Sequence[float], seq_len: int, anchor: str = "centre",
                 reverse: bool = False) -> list[tuple[int, ...]]:
    """The distinct reference offsets ``[L]`` (relative to the item's start b) of each slope, in slope order."""
    p = pivot_step(anchor, seq_len)
    out: list[tuple[int, ...]] = []
    for v in check_velocities(velocities):
        steps = [round_half_away(v * (t - p)) for t in range(seq_len)]
        offs = tuple((seq_len - 1 - p - s) if reverse else (p + s) for s in steps)
        if offs not in out:
            out.append(offs)
    return out


def check_pairs(q: torch.Tensor, r: torch.Tensor, seq_len: int, q_starts: torch.Tensor,
                cand: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Validate window pairs ``q_starts [M]`` × ``cand [M, K]`` (-1 = none); returns both as int64."""
    check_seq_len(seq_len, min(q.shape[0], r.shape[0]), "seq_len")
    cand, q_starts = torch.as_tensor(cand).long(), torch.as_tensor(q_starts).long()
    if cand.ndim != 2 or q_starts.ndim != 1 or cand.shape[0] != q_starts.shape[0]:
        raise ConfigError(f"window pairs need query starts [M] and candidates [M, K], got "
                          f"{tuple(q_starts.shape)} and {tuple(cand.shape)}")
    nb = r.shape[0] - seq_len + 1
    if cand.numel() and (cand.min() < -1 or cand.max() >= nb):
        raise ConfigError(f"candidate window starts must lie in 0..{nb - 1} (or -1 for none)")
    if q_starts.numel() and (q_starts.min() < 0 or q_starts.max() > q.shape[0] - seq_len):
        raise ConfigError(f"query window starts must lie in 0..{q.shape[0] - seq_len}")
    return q_starts.to(q.device), cand.to(q.device)


class FrameDistances:
    """A precomputed ``[Nq, Nr]`` frame-distance matrix standing in for the query descriptors of
    :func:`matcher_topk` (then ``ref`` is unused): its rows are the distance blocks, no GEMM (distance
    matrices from other tools: :class:`seqnet.reference.matrix.MatrixReference`)."""

    def __init__(self, dist: torch.Tensor) -> None:
        self.dist = dist
        self.shape, self.dtype, self.device = tuple(dist.shape), dist.dtype, dist.device

    def element_size(self) -> int:
        return self.dist.element_size()

    def rows(self, a: int, b: int) -> torch.Tensor:
        return self.dist[a:b].clone()  # the block functions may work in place

    def reference(self) -> torch.Tensor:
        """A stand-in of the reference side with its number of frames (the block functions need only that)."""
        return self.dist.new_empty((self.shape[1], 0))


def score_blocks(block_fn: BlockFn, q: torch.Tensor, r: torch.Tensor, seq_len: int, row_factor: int,
                 block_bytes: int | None = None, starts: np.ndarray | None = None,
                 desc: str | None = None) -> Iterator[tuple[int, torch.Tensor]]:
    """Yield ``(a0, block_fn(dist, a0, n))`` over blocks of n query windows starting at ``a0``.

    ``dist [n + L − 1, Nr]`` are the Euclidean distances of query frames ``a0 .. a0 + n + L − 2`` to
    every reference frame (one GEMM; rows of the matrix when ``q`` is :class:`FrameDistances`). A block
    is about ``row_factor`` ``[n, Nr]`` buffers within ``block_bytes``. With sorted ``starts``, blocks
    that hold none of them are skipped.
    """
    na = q.shape[0] - seq_len + 1
    rows = rows_per_block(row_factor * r.shape[0] * q.element_size(), block_bytes)
    if isinstance(q, FrameDistances):  # given distances: rows of the matrix
        dist_rows = q.rows
    else:
        q_sq, r_sq = sq_norms(q), sq_norms(r)

        def dist_rows(a0: int, e: int) -> torch.Tensor:  # SeqMatch's own kernel: velocity 1 is SeqMatch exactly
            d = torch.empty((e - a0, r.shape[0]), dtype=q.dtype, device=q.device)
            distances(d, q[a0:e], q_sq[a0:e], r, r_sq)
            return d
    for a0 in progress(range(0, na, rows), desc=desc):
        n = min(rows, na - a0)
        if starts is not None and np.searchsorted(starts, a0) == np.searchsorted(starts, a0 + n):
            continue
        yield a0, block_fn(dist_rows(a0, a0 + n + seq_len - 1), a0, n)


@no_grad
def matcher_topk(prepare: Callable[[torch.Tensor, torch.Tensor], BlockFn], query: ArrayLike, ref: ArrayLike,
                 seq_len: int, k: int, q_starts: np.ndarray, r_starts: np.ndarray, row_factor: int,
                 device: str | None = None, block_bytes: int | None = None,
                 desc: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Whole-map top-k of any blockwise matcher (ties by the lower item index).

    ``prepare(q, r)`` (on validated tensors) returns the block function: ``(dist, a0, n)`` →
    ``[n, Nr − L + 1]`` scores of windows ``a0 .. a0 + n − 1``. Query item m is the window at
    ``q_starts[m]``, reference item j the one at ``r_starts[j]``. Returns ``(scores [M, k],
    items [M, k])`` as numpy.
    """
    dev = get_device(device)
    q, r = (query, query.reference()) if isinstance(query, FrameDistances) else as_pair(query, ref, dev)
    check_seq_len(seq_len, min(q.shape[0], r.shape[0]), "seq_len")
    k = check_int("k", k, 1)
    q_starts = check_starts(q_starts, q.shape[0] - seq_len + 1, "query")
    r_cols = torch.as_tensor(check_starts(r_starts, r.shape[0] - seq_len + 1, "reference"), device=dev)
    block_fn = prepare(q, r)
    order = np.argsort(q_starts, kind="stable")
    sorted_starts = q_starts[order]

    def row_blocks():
        for a0, m in score_blocks(block_fn, q, r, seq_len, row_factor, block_bytes, sorted_starts, desc):
            lo, hi = np.searchsorted(sorted_starts, [a0, a0 + m.shape[0]])
            yield torch.as_tensor(order[lo:hi]), m[torch.as_tensor(sorted_starts[lo:hi] - a0, device=dev)]

    all_items = torch.arange(len(r_cols), device=dev)
    return blocked_topk(row_blocks(), [r_cols], lambda m, cols: (m[:, cols], all_items), len(q_starts),
                        min(k, len(r_cols)), q.dtype, finite=False)


def velocity_block(dist: torch.Tensor, a0: int, n: int, trajs: list[tuple[int, ...]], nb: int) -> torch.Tensor:
    """``[n, nb]`` scores of windows ``a0 ..`` from their distances ``dist [n + L − 1, Nr]`` (any ``a0``)."""
    n_ref = dist.shape[1]
    best = torch.full((n, nb), math.inf, dtype=dist.dtype, device=dist.device)
    tmp = torch.empty_like(best)
    for offs in trajs:
        lo, hi = min(offs), max(offs)
        b_lo, b_hi = max(0, -lo), min(nb, n_ref - hi)  # items whose trajectory stays inside
        if b_hi <= b_lo:
            continue
        part = shifted_sum(dist[:, b_lo + lo :], 0, n, [o - lo for o in offs], b_hi - b_lo, tmp[:, : b_hi - b_lo])
        torch.minimum(best[:, b_lo:b_hi], part, out=best[:, b_lo:b_hi])
    return best


def _prepare(velocities: Sequence[float], reverse: bool, anchor: str, seq_len: int) -> Callable[..., BlockFn]:
    trajs = trajectories(velocities, seq_len, anchor, reverse)
    return lambda q, r: functools.partial(velocity_block, trajs=trajs, nb=r.shape[0] - seq_len + 1)


def velocity_topk(query: ArrayLike, ref: ArrayLike, seq_len: int, k: int, q_starts: np.ndarray,
                  r_starts: np.ndarray, velocities: Sequence[float] = DEFAULT_VELOCITIES, reverse: bool = False,
                  anchor: str = "centre", device: str | None = None,
                  block_bytes: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Whole-map velocity-robust SeqMatch, the k best reference items per query item.

    ``query [Nq, D]``, ``ref [Nr, D]``; items are windows starting at ``q_starts [M]`` /
    ``r_starts [R]``. Returns ``(scores [M, k], items [M, k])`` (indices into ``r_starts``).
    """
    check_seq_len(seq_len)
    return matcher_topk(_prepare(velocities, reverse, anchor, seq_len), query, ref, seq_len, k, q_starts,
                        r_starts, 3, device, block_bytes, "velocity SeqMatch")


def velocity_map(query: ArrayLike, ref: ArrayLike, seq_len: int, velocities: Sequence[float] = DEFAULT_VELOCITIES,
                 reverse: bool = False, anchor: str = "centre", device: str | None = None,
                 block_bytes: int | None = None) -> np.ndarray:
    """The whole ``[Nq − L + 1, Nr − L + 1]`` velocity-robust SeqMatch map (numpy)."""
    check_seq_len(seq_len)
    q, r = as_pair(query, ref, get_device(device))
    check_seq_len(seq_len, min(q.shape[0], r.shape[0]), "seq_len")
    block_fn = _prepare(velocities, reverse, anchor, seq_len)(q, r)
    return np.concatenate([to_numpy(m) for _, m in score_blocks(block_fn, q, r, seq_len, 3, block_bytes)])


@no_grad
def velocity_pairs(q: torch.Tensor, r: torch.Tensor, seq_len: int, q_starts: torch.Tensor, cand: torch.Tensor,
                   velocities: Sequence[float] = DEFAULT_VELOCITIES, reverse: bool = False,
                   anchor: str = "centre", block_bytes: int | None = None) -> torch.Tensor:
    """Velocity-robust SeqMatch scores ``[M, K]`` of query windows ``q_starts [M]`` vs ``cand [M, K]``.

    ``q [Nq, D]``, ``r [Nr, D]`` tensors on one device; candidates equal to -1 score ``inf``.
    Each distinct (step, reference offset) distance is computed once per block.
    """
    q_starts, cand = check_pairs(q, r, seq_len, q_starts, cand)
    trajs = trajectories(velocities, seq_len, anchor, reverse)
    out = torch.full(cand.shape, math.inf, dtype=q.dtype, device=q.device)
    rows = rows_per_block(max(1, cand.shape[1]) * q.shape[1] * q.element_size() * 2, block_bytes)
    safe = cand.clamp_min(0)
    for s in range(0, cand.shape[0], rows):
        qs, cs = q_starts[s : s + rows], safe[s : s + rows]
        dist: dict[tuple[int, int], torch.Tensor] = {}
        for offs in trajs:
            for t, o in enumerate(offs):
                if (t, o) not in dist:
                    frames = cs + o
                    inside = (frames >= 0) & (frames < r.shape[0])
                    d = (r[frames.clamp(0, r.shape[0] - 1)] - q[qs + t][:, None, :]).norm(dim=-1)
                    dist[(t, o)] = d.masked_fill_(~inside, math.inf)
            total = functools.reduce(torch.add, (dist[(t, o)] for t, o in enumerate(offs)))
            torch.minimum(out[s : s + rows], total, out=out[s : s + rows])
    return out.masked_fill_(cand < 0, math.inf)
