"""SeqMatch: summed frame distances along aligned windows, over the whole map or given pairs.

SeqMatch (Milford & Wyeth 2012; SeqNet paper):
``M[a, b] = Σ_{t=0}^{L-1} ‖query[a+t] − ref[b+t]‖₂`` over window start indices ``a, b``; the lowest
score wins. With ``reverse=True`` the reference is traversed the other way:
``Σ_t ‖query[a+t] − ref[b+L−1−t]‖₂``.

Whole-map scores are fused in cache-sized tiles (:mod:`seqnet.matching.banded`): per tile one GEMM
with the norm trick and one sum of the L diagonals (or anti-diagonals), written once into the result.
"""

from __future__ import annotations

import numpy as np

from ..core.config import check_int
from ..core.devices import get_device
from ..core.errors import ConfigError
from ..core.lazy import lazy_module, no_grad
from ..core.progress import progress
from ..core.tensors import ArrayLike, as_tensor, to_numpy
from ..search.api import prepared
from ..search.blocks import FINITE_HINT, blocked_topk, check_pair_dims, col_blocks, rows
from ..search.knn import as_pair, rows_per_block, sq_norms
from ..search.precision import compute_dtype
from ..sequence.windows import check_seq_len
from .banded import banded_map, tile_budget
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
    tile_bytes: int | None = None,
    normalize: bool | None = None,
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
        tile_bytes: distances per fused tile of the whole map (default cache-sized on the CPU,
            :data:`seqnet.matching.banded.TILE_BYTES`; at most ``block_bytes``).
        normalize: ``True``: L2-normalise every frame's row first, as ``evaluate()`` and ``seqnet eval``
            (``raw+seqmatch``) do; ``None`` (default): the rows as given, with a WARNING line when they are far
            from unit norm (then the scores rank otherwise than the evaluation's); ``False``: as given, without the
            unit-norm check. Any ``normalize``: a row with NaN / inf is refused, all-zero rows are said (one line).

    Returns:
        ``[Nq−L+1, Nr−L+1]`` scores (or ``[Nq−L+1, K]`` with candidates), numpy if ``query`` is
        numpy else a torch tensor on ``query``'s device. float64 inputs stay float64.
    """
    dev, given = get_device(device), query
    query, ref = prepared(query, ref, "seqmatch", normalize)
    if candidates is None:
        q, r, norms = _pair_norms(query, ref, dev)
        check_seq_len(seq_len, min(q.shape[0], r.shape[0]), "seq_len")
        out = banded_map(q, r, seq_len, reverse, tile_budget(dev, tile_bytes, block_bytes), norms)
        maybe_nan = not nan_free(*norms, q.dtype)
    else:
        out, maybe_nan = _candidate_scores(query, ref, seq_len, candidates, reverse, dev, block_bytes), True
    if maybe_nan and bool(torch.isnan(out).any()):
        raise ConfigError("SeqMatch scores hold NaN: the descriptors hold NaN or inf, or values too large for "
                          f"{str(out.dtype).removeprefix('torch.')} ({FINITE_HINT})")
    if isinstance(given, torch.Tensor):
        return out.to(given.device)
    return to_numpy(out)


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
    m = banded_map(qf, rf, seq_len, reverse, tile_budget(qf.device, None, None))  # every window pair of the blocks
    return m[q_windows][:, r_windows]


def _candidate_scores(query: ArrayLike, ref: ArrayLike, seq_len: int, candidates: ArrayLike, reverse: bool,
                      dev: torch.device, block_bytes: int | None) -> torch.Tensor:
    """:func:`seqmatch` of the candidate windows only: ``[Nq−L+1, K]``."""
    q, r = as_pair(query, ref, dev)
    check_seq_len(seq_len, min(q.shape[0], r.shape[0]), "seq_len")
    cand = candidates if isinstance(candidates, torch.Tensor) else torch.as_tensor(np.asarray(candidates))
    na = q.shape[0] - seq_len + 1
    if cand.ndim != 2 or cand.shape[0] != na:
        raise ConfigError(f"candidates must be [{na}, K] (one row per query window), got {tuple(cand.shape)}")
    if cand.is_floating_point() and cand.numel() and not bool((cand == cand.round()).all()):
        raise ConfigError("candidates must be integer window starts (or -1 for none)")
    starts = torch.arange(na, device=dev)
    return window_scores(q, r, seq_len, starts, cand.to(dev), reverse, block_bytes)


def _pair_norms(query: ArrayLike, ref: ArrayLike,
                dev: torch.device) -> tuple[torch.Tensor, torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
    """:func:`seqnet.search.knn.as_pair`'s ``(q, r)`` (and its errors) and their squared row norms, computed once."""
    q = as_tensor(query, dev, "query", ndim=2, keep_float64=True)
    r = as_tensor(ref, dev, "reference", ndim=2, keep_float64=True)
    if q.shape[1] != r.shape[1]:
        as_pair(query, ref, dev)  # raises its dimension-mismatch error
    r = r.to(q.dtype)
    norms = sq_norms(q), sq_norms(r)
    if not (bool(torch.isfinite(norms[0]).all()) and bool(torch.isfinite(norms[1]).all())):
        as_pair(query, ref, dev)  # raises its error: NaN or inf, or norms that overflow
    return q, r, norms


def nan_free(q_sq: torch.Tensor, r_sq: torch.Tensor, dtype: torch.dtype) -> bool:
    """Whether no SeqMatch score can be NaN: finite norms with ``max ‖q‖² + max ‖r‖²`` under a quarter of
    the dtype's largest value (then ``|2 q·r| ≤ ‖q‖² + ‖r‖²`` and every step stays finite), so the result
    needs no check."""
    top = float(q_sq.max()) + float(r_sq.max())
    return top < float(torch.finfo(dtype).max) / 4


def check_starts(starts: ArrayLike, n: int, side: str) -> np.ndarray:
    """Validate window starts: a 1-D integer array with values in ``0..n-1``; returns int64 numpy."""
    a = np.asarray(to_numpy(starts) if isinstance(starts, torch.Tensor) else starts)
    if a.ndim != 1 or (a.size and a.dtype.kind not in "iu"):
        raise ConfigError(f"{side} window starts must be a 1-D integer array, got shape {a.shape}, dtype {a.dtype}")
    a = a.astype(np.int64, copy=False)
    if a.size and (a.min() < 0 or a.max() >= n):
        raise ConfigError(f"{side} window starts must lie in 0..{n - 1}, got values in {a.min()}..{a.max()}")
    return a
