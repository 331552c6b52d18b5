"""SeqMatch: summed frame distances along aligned windows, over the whole map or given pairs.

SeqMatch (Milford & Wyeth 2012; SeqNet paper):
``M[a, b] = Σ_{t=0}^{L-1} ‖query[a+t] − ref[b+t]‖₂`` over window start indices ``a, b``; the lowest
score wins. With ``reverse=True`` the reference is traversed the other way:
``Σ_t ‖query[a+t] − ref[b+L−1−t]‖₂``.

Whole-map scores are one distance matrix per query block (a GEMM with the norm trick) plus L
shifted (diagonal or anti-diagonal) sums; blocks keep memory bounded.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from ..core.config import check_int
from ..core.devices import get_device
from ..core.errors import ConfigError
from ..core.lazy import lazy_module, no_grad
from ..core.progress import progress
from ..core.tensors import ArrayLike, to_numpy
from ..search.blocks import blocked_topk, check_pair_dims, col_blocks, rows
from ..search.knn import as_pair, finish_distances, rows_per_block, sq_norms
from ..search.precision import compute_dtype
from ..sequence.windows import check_seq_len
from .pairs import window_scores

torch = lazy_module("torch")


@no_grad
def seqmatch(
    query: ArrayLike,
    ref: ArrayLike,
    seq_len: int,
    candidates: ArrayLike | None = None,
    reverse: bool = False,
    device: str | None = None,
    block_bytes: int | None = None,
    chunk_bytes: int | None = None,
) -> ArrayLike:
    """SeqMatch scores between all query and reference windows (or candidate windows only).

    Args:
        query: ``[Nq, D]`` single-image descriptors (numpy or torch).
        ref: ``[Nr, D]`` single-image descriptors.
        seq_len: L ≥ 1, at most ``min(Nq, Nr)``.
        candidates: optional ``[Nq−L+1, K]`` reference window starts per query window
            (``-1`` = no candidate, scored ``inf``).
        reverse: pair ``query[a+t]`` with ``ref[b+L−1−t]``.
        device: computation device (default: CUDA when available, else CPU).
        block_bytes: memory budget per block (default 64 MiB, :data:`seqnet.search.knn.DEFAULT_BLOCK_BYTES`).
        chunk_bytes: see :func:`full_blocks` (CPU tuning knob; default whole-block passes).

    Returns:
        ``[Nq−L+1, Nr−L+1]`` scores (or ``[Nq−L+1, K]`` with candidates), numpy if ``query`` is
        numpy else a torch tensor on ``query``'s device. float64 inputs stay float64.
    """
    dev = get_device(device)
    q, r = as_pair(query, ref, dev)
    check_seq_len(seq_len, min(q.shape[0], r.shape[0]), "seq_len")
    if candidates is None:
        out = _full_map(q, r, seq_len, reverse, block_bytes, chunk_bytes)
    else:
        cand = candidates if isinstance(candidates, torch.Tensor) else torch.as_tensor(np.asarray(candidates))
        na = q.shape[0] - seq_len + 1
        if cand.ndim != 2 or cand.shape[0] != na:
            raise ConfigError(f"candidates must be [{na}, K] (one row per query window), got {tuple(cand.shape)}")
        if cand.is_floating_point() and cand.numel() and not bool((cand == cand.round()).all()):
            raise ConfigError("candidates must be integer window starts (or -1 for none)")
        starts = torch.arange(na, device=dev)
        out = window_scores(q, r, seq_len, starts, cand.to(dev), reverse, block_bytes)
    if bool(torch.isnan(out).any()):
        raise ConfigError("SeqMatch scores hold NaN: the descriptors hold NaN or inf, or values too large for "
                          f"{str(out.dtype).removeprefix('torch.')} (hint: L2-normalise them)")
    if isinstance(query, torch.Tensor):
        return out.to(query.device)
    return to_numpy(out)


def _chunk_rows(q: torch.Tensor, r: torch.Tensor, n: int, chunk_bytes: int | None) -> int:
    """Rows per chunk for the element-wise passes over a block of ``n`` rows."""
    if q.device.type != "cpu" or chunk_bytes is None:
        return max(1, n)
    return max(8, chunk_bytes // max(1, r.shape[0] * q.element_size()))


def block_rows(q: torch.Tensor, r: torch.Tensor, block_bytes: int | None) -> int:
    """Query windows per block: the distance block and the score block fit the budget."""
    return rows_per_block(2 * r.shape[0] * q.element_size(), block_bytes)


def _full_map(q: torch.Tensor, r: torch.Tensor, seq_len: int, reverse: bool, block_bytes: int | None,
              chunk_bytes: int | None) -> torch.Tensor:
    """The whole ``[Nq−L+1, Nr−L+1]`` SeqMatch map (one block: computed inside the GEMM's buffer)."""
    na, nb = q.shape[0] - seq_len + 1, r.shape[0] - seq_len + 1
    if na <= block_rows(q, r, block_bytes):
        return next(full_blocks(q, r, seq_len, reverse, block_bytes, chunk_bytes))[1]
    out = torch.empty((na, nb), dtype=q.dtype, device=q.device)
    for _ in full_blocks(q, r, seq_len, reverse, block_bytes, chunk_bytes, out=out):
        pass
    return out


def full_blocks(
    q: torch.Tensor,
    r: torch.Tensor,
    seq_len: int,
    reverse: bool = False,
    block_bytes: int | None = None,
    chunk_bytes: int | None = None,
    out: torch.Tensor | None = None,
) -> Iterator[tuple[int, torch.Tensor]]:
    """Yield ``(first_window, M[block, Nr−L+1])`` over blocks of query windows.

    Per block: one GEMM ``q[a0 : a1+L−1] @ r.T`` (the only pass over D), then, in place, the norm
    trick + sqrt (4 element-wise passes) and the L shifted sums (L − 1 passes) written straight
    into the result: ``out[a0:a1]`` when ``out`` is given, else a new buffer.

    ``chunk_bytes`` (CPU only): finalise and sum the distance rows in cache-sized chunks (e.g.
    1 MiB) instead of whole-block passes. Chunks read the distance block back from memory only once
    and are fastest on an idle machine, but each costs ~10 parallel regions (thread barriers), which
    dominate on an oversubscribed machine; whole-block passes (None, the default) stay within ~10%
    of the bare GEMM either way. Each chunk is summed into a small buffer and packed row by row into
    the front of the GEMM's own buffer (score row ``a`` only overwrites distance rows ``<= a``, which
    no later chunk reads), so the block needs no second ``[rows, Nr]`` buffer.
    """
    na, nb = q.shape[0] - seq_len + 1, r.shape[0] - seq_len + 1
    rows = block_rows(q, r, block_bytes)
    r_sq, q_sq = sq_norms(r), sq_norms(q)
    chunk = _chunk_rows(q, r, min(rows, na), chunk_bytes)
    cols = [(seq_len - 1 - t) if reverse else t for t in range(seq_len)]  # reference shift of frame t
    for a0 in range(0, na, rows):
        a1 = min(na, a0 + rows)
        n = a1 - a0
        dist = torch.mm(q[a0 : a1 + seq_len - 1], r.T)  # [n + L - 1, Nr] inner products
        if out is not None:
            dest = out[a0:a1]
        elif chunk >= n:  # one chunk: sum straight into a new buffer
            dest = torch.empty((n, nb), dtype=q.dtype, device=q.device)
        else:  # sum each chunk into a small buffer, then pack it into the front of ``dist``
            dest, tmp = None, torch.empty((chunk, nb), dtype=q.dtype, device=q.device)
        packed = dist.view(-1)
        done = 0  # rows of ``dist`` already turned into distances
        for s in range(0, n, chunk):
            e = min(n, s + chunk)
            if e + seq_len - 1 > done:
                finish_distances(dist[done : e + seq_len - 1], q_sq[a0 + done : a0 + e + seq_len - 1], r_sq)
                done = e + seq_len - 1
            ms = dest[s:e] if dest is not None else tmp[: e - s]
            shifted_sum(dist, s, e, cols, nb, ms)
            if dest is None:
                packed[s * nb : e * nb].view(e - s, nb).copy_(ms)
        yield a0, (dest if dest is not None else packed[: n * nb].view(n, nb))


def shifted_sum(dist: torch.Tensor, s: int, e: int, cols: list[int], nb: int, out: torch.Tensor) -> torch.Tensor:
    """``out[i - s, b] = Σ_t dist[i + t, b + cols[t]]`` for rows ``i in [s, e)``: the L shifted adds."""
    if len(cols) == 1:
        return out.copy_(dist[s:e, cols[0] : cols[0] + nb])
    torch.add(dist[s:e, cols[0] : cols[0] + nb], dist[s + 1 : e + 1, cols[1] : cols[1] + nb], out=out)
    for t in range(2, len(cols)):
        out.add_(dist[s + t : e + t, cols[t] : cols[t] + nb])
    return out


@no_grad
def seqmatch_topk(
    query: ArrayLike,
    ref: ArrayLike,
    seq_len: int,
    k: int,
    q_starts: np.ndarray,
    r_starts: np.ndarray,
    reverse: bool = False,
    device: str | None = None,
    block_bytes: int | None = None,
    col_block: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Whole-map SeqMatch, keeping the k best reference items per query item.

    Query item m is the window starting at ``q_starts[m]``; reference item j the window starting
    at ``r_starts[j]``. Returns ``(scores [M, k], items [M, k])`` (indices into ``r_starts``),
    ties broken by the lower reference window start. Memory stays bounded for any map size (blocks
    of query × ``col_block`` reference windows of possibly memory-mapped or float16 arrays, running
    top-k: :mod:`seqnet.search.blocks`).
    """
    dev, dtype = get_device(device), compute_dtype(query, ref)
    nq, nr, _ = check_pair_dims(query, ref)
    check_seq_len(seq_len, min(nq, nr), "seq_len")
    k = check_int("k", k, 1)
    na, nb = nq - seq_len + 1, nr - seq_len + 1
    q_starts, r_starts = check_starts(q_starts, na, "query"), check_starts(r_starts, nb, "reference")
    q_order, r_order = np.argsort(q_starts, kind="stable"), np.argsort(r_starts, kind="stable")
    q_sorted, r_sorted = q_starts[q_order], r_starts[r_order]
    cols = col_blocks(nb, col_block, check_pair_dims(query, ref)[2] * (8 if dtype == torch.float64 else 4))
    width = max(c1 - c0 for c0, c1 in cols) + seq_len - 1
    step = rows_per_block(2 * width * (8 if dtype == torch.float64 else 4), block_bytes)
    ref_all = rows(ref, 0, nr, dev, dtype) if len(cols) == 1 else None  # a map that fits one block: read once

    def row_blocks():  # query windows a0..a1 that hold items, in start order
        for a0 in progress(range(0, na, step), desc="SeqMatch"):
            lo, hi = np.searchsorted(q_sorted, [a0, min(na, a0 + step)])
            if lo < hi:
                qf = rows(query, a0, min(na, a0 + step) + seq_len - 1, dev, dtype)
                yield torch.as_tensor(q_order[lo:hi]), (qf, torch.as_tensor(q_sorted[lo:hi] - a0, device=dev))

    def score(ctx: tuple[torch.Tensor, torch.Tensor], cb: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
        (qf, local_q), (c0, c1) = ctx, cb
        rf = ref_all if ref_all is not None else rows(ref, c0, c1 + seq_len - 1, dev, dtype)
        j0, j1 = np.searchsorted(r_sorted, [c0, c1])
        local_r = torch.as_tensor(r_sorted[j0:j1] - c0, device=dev)
        return _block_scores(qf, rf, seq_len, reverse, local_q, local_r), torch.as_tensor(r_order[j0:j1], device=dev)

    return blocked_topk(row_blocks(), cols, score, len(q_starts), min(k, len(r_starts)), dtype)


def _block_scores(qf: torch.Tensor, rf: torch.Tensor, seq_len: int, reverse: bool, q_windows: torch.Tensor,
                  r_windows: torch.Tensor) -> torch.Tensor:
    """SeqMatch scores ``[len(q_windows), len(r_windows)]`` of windows (starts local to the frame blocks)."""
    m = next(full_blocks(qf, rf, seq_len, reverse, block_bytes=2**62))[1]  # every window pair of the blocks
    return m[q_windows][:, r_windows]


def check_starts(starts: ArrayLike, n: int, side: str) -> np.ndarray:
    """Validate window starts: a 1-D integer array with values in ``0..n-1``; returns int64 numpy."""
    a = np.asarray(to_numpy(starts) if isinstance(starts, torch.Tensor) else starts)
    if a.ndim != 1 or (a.size and a.dtype.kind not in "iu"):
        raise ConfigError(f"{side} window starts must be a 1-D integer array, got shape {a.shape}, dtype {a.dtype}")
    a = a.astype(np.int64, copy=False)
    if a.size and (a.min() < 0 or a.max() >= n):
        raise ConfigError(f"{side} window starts must lie in 0..{n - 1}, got values in {a.min()}..{a.max()}")
    return a
