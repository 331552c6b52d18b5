"""SeqMatch and HVPR.

SeqMatch (Milford & Wyeth 2012; SeqNet paper):
``M[a, b] = Σ_{t=0}^{L-1} ‖query[a+t] − ref[b+t]‖₂`` over window start indices ``a, b``; the lowest
score wins. With ``reverse=True`` the reference is traversed the other way:
``Σ_t ‖query[a+t] − ref[b+L−1−t]‖₂``.

Computed as one distance matrix per query block (a GEMM with the norm trick) plus L shifted
(diagonal or anti-diagonal) sums; blocks keep memory bounded.

HVPR (hierarchical VPR): shortlist the top-K references with any sequence or single descriptor,
then re-rank the shortlist by SeqMatch on single descriptors.
"""

from __future__ import annotations

from typing import Iterator

import numpy as np
import torch
from tqdm.auto import tqdm

from .errors import ConfigError
from .matching import _check_pair, _rows_per_block, _tensor, knn, pairwise_distances, topk_smallest
from .utils import ArrayLike, get_device, to_numpy
from .windows import check_seq_len


def seqmatch(
    query: ArrayLike,
    ref: ArrayLike,
    seq_len: int,
    candidates: ArrayLike | None = None,
    reverse: bool = False,
    device: str | None = None,
    block_bytes: int | None = None,
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
        block_bytes: memory budget per block (default 512 MiB).

    Returns:
        ``[Nq−L+1, Nr−L+1]`` scores (or ``[Nq−L+1, K]`` with candidates), numpy if ``query`` is
        numpy else a torch tensor on ``query``'s device. float64 inputs stay float64.
    """
    dev = get_device(device)
    q, r = _tensor(query, dev, "query"), _tensor(ref, dev, "reference")
    r = _check_pair(q, r)
    check_seq_len(seq_len, min(q.shape[0], r.shape[0]), "seq_len")
    if candidates is None:
        out = torch.cat([m for _, m in _full_blocks(q, r, seq_len, reverse, block_bytes)])
    else:
        cand = torch.as_tensor(to_numpy(candidates) if not isinstance(candidates, torch.Tensor) else candidates)
        na = q.shape[0] - seq_len + 1
        if cand.ndim != 2 or cand.shape[0] != na:
            raise ConfigError(f"candidates must be [{na}, K] (one row per query window), got {tuple(cand.shape)}")
        starts = torch.arange(na, device=dev)
        out = window_scores(q, r, seq_len, starts, cand.to(dev), reverse, block_bytes)
    if isinstance(query, torch.Tensor):
        return out.to(query.device)
    return to_numpy(out)


def _block_rows(q: torch.Tensor, r: torch.Tensor, seq_len: int, block_bytes: int | None) -> int:
    """Query windows per block: the distance block and the score block fit the budget."""
    return max(seq_len, _rows_per_block(2 * r.shape[0] * q.element_size(), block_bytes))


def _full_blocks(
    q: torch.Tensor, r: torch.Tensor, seq_len: int, reverse: bool, block_bytes: int | None
) -> Iterator[tuple[int, torch.Tensor]]:
    """Yield ``(first_window, M[block, Nr−L+1])`` over blocks of query windows."""
    na, nb = q.shape[0] - seq_len + 1, r.shape[0] - seq_len + 1
    rows = _block_rows(q, r, seq_len, block_bytes)
    for a0 in range(0, na, rows):
        a1 = min(na, a0 + rows)
        dist = pairwise_distances(q[a0 : a1 + seq_len - 1], r)
        m = dist[: a1 - a0, (seq_len - 1 if reverse else 0) :][:, :nb].clone()
        for t in range(1, seq_len):
            c = seq_len - 1 - t if reverse else t
            m.add_(dist[t : t + a1 - a0, c : c + nb])
        yield a0, m


def window_scores(
    q: torch.Tensor,
    r: torch.Tensor,
    seq_len: int,
    q_starts: torch.Tensor,
    cand: torch.Tensor,
    reverse: bool = False,
    block_bytes: int | None = None,
) -> torch.Tensor:
    """SeqMatch scores of given window pairs: query windows ``q_starts [M]`` vs ``cand [M, K]``.

    Returns ``[M, K]``; candidates equal to -1 score ``inf``. Validates the index ranges.
    """
    nb = r.shape[0] - seq_len + 1
    cand = cand.long()
    if cand.numel() and (cand.min() < -1 or cand.max() >= nb):
        raise ConfigError(f"candidate window starts must lie in 0..{nb - 1} (or -1 for none)")
    if q_starts.numel() and (q_starts.min() < 0 or q_starts.max() > q.shape[0] - seq_len):
        raise ConfigError(f"query window starts must lie in 0..{q.shape[0] - seq_len}")
    m, k = cand.shape
    out = torch.zeros((m, k), dtype=q.dtype, device=q.device)
    rows = _rows_per_block(max(1, k) * q.shape[1] * q.element_size() * 2, block_bytes)
    missing = cand < 0
    safe = cand.clamp_min(0)
    for s in range(0, m, rows):
        qs, cs = q_starts[s : s + rows], safe[s : s + rows]
        for t in range(seq_len):
            rt = seq_len - 1 - t if reverse else t
            diff = r[cs + rt] - q[qs + t][:, None, :]
            out[s : s + rows] += diff.norm(dim=-1)
    return out.masked_fill_(missing, float("inf"))


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
    progress: str | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Whole-map SeqMatch, keeping the k best reference items per query item.

    Query item m is the window starting at ``q_starts[m]``; reference item j the window starting
    at ``r_starts[j]``. Returns ``(scores [M, k], items [M, k])`` (indices into ``r_starts``).
    """
    dev = get_device(device)
    q, r = _tensor(query, dev, "query"), _tensor(ref, dev, "reference")
    r = _check_pair(q, r)
    check_seq_len(seq_len, min(q.shape[0], r.shape[0]), "seq_len")
    q_starts, r_cols = np.asarray(q_starts, np.int64), torch.as_tensor(np.asarray(r_starts, np.int64), device=dev)
    order = np.argsort(q_starts, kind="stable")
    vals = torch.zeros((len(q_starts), min(k, len(r_starts))), dtype=q.dtype, device=dev)
    idx = torch.zeros(vals.shape, dtype=torch.long, device=dev)
    na = q.shape[0] - seq_len + 1
    rows = _block_rows(q, r, seq_len, block_bytes)
    blocks = _full_blocks(q, r, seq_len, reverse, block_bytes)
    n_blocks = -(-na // rows)
    for a0, m in tqdm(blocks, total=n_blocks, desc=progress, disable=progress is None or n_blocks < 2, leave=False):
        lo, hi = np.searchsorted(q_starts[order], [a0, a0 + m.shape[0]])
        sel = order[lo:hi]
        if sel.size == 0:
            continue
        rows = torch.as_tensor(q_starts[sel] - a0, device=dev)
        v, i = topk_smallest(m[rows][:, r_cols], k)
        sel_t = torch.as_tensor(sel, device=dev)
        vals[sel_t], idx[sel_t] = v, i
    return to_numpy(vals), to_numpy(idx)


def hvpr(
    shortlist_query: ArrayLike,
    shortlist_ref: ArrayLike,
    rerank_query: ArrayLike,
    rerank_ref: ArrayLike,
    seq_len: int,
    q_starts: np.ndarray,
    r_starts: np.ndarray,
    top_k: int = 20,
    reverse: bool = False,
    backend: str = "torch",
    device: str | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Hierarchical VPR: shortlist by descriptor distance, re-rank by SeqMatch.

    Args:
        shortlist_query: ``[M, D1]`` shortlisting descriptors of the query items (e.g. S_L).
        shortlist_ref: ``[R, D1]`` shortlisting descriptors of the reference items.
        rerank_query: ``[Nq, D2]`` single-image descriptors of all query frames (raw or S_1).
        rerank_ref: ``[Nr, D2]`` single-image descriptors of all reference frames.
        seq_len: SeqMatch length L_m.
        q_starts: ``[M]`` SeqMatch window start (in ``rerank_query``) of each query item.
        r_starts: ``[R]`` SeqMatch window start (in ``rerank_ref``) of each reference item.
        top_k: shortlist size K (default 20).

    Returns:
        ``(items [M, K], scores [M, K])``: reference items ranked by SeqMatch score (ascending).
    """
    if top_k < 1:
        raise ConfigError(f"top_k must be >= 1, got {top_k}")
    _, cand = knn(shortlist_query, shortlist_ref, top_k, backend=backend, device=device)
    return rerank_seqmatch(rerank_query, rerank_ref, seq_len, q_starts, r_starts, cand, reverse, device)


def rerank_seqmatch(
    rerank_query: ArrayLike,
    rerank_ref: ArrayLike,
    seq_len: int,
    q_starts: np.ndarray,
    r_starts: np.ndarray,
    candidates: np.ndarray,
    reverse: bool = False,
    device: str | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Re-rank candidate reference items ``[M, K]`` by SeqMatch (see :func:`hvpr`).

    Returns ``(items [M, K], scores [M, K])`` sorted by ascending score (stable: ties keep the
    shortlist order).
    """
    dev = get_device(device)
    q, r = _tensor(rerank_query, dev, "query"), _tensor(rerank_ref, dev, "reference")
    r = _check_pair(q, r)
    check_seq_len(seq_len, min(q.shape[0], r.shape[0]), "seq_len")
    r_starts_t = torch.as_tensor(np.asarray(r_starts, np.int64), device=dev)
    cand_t = torch.as_tensor(np.asarray(candidates, np.int64), device=dev)
    q_starts_t = torch.as_tensor(np.asarray(q_starts, np.int64), device=dev)
    scores = window_scores(q, r, seq_len, q_starts_t, r_starts_t[cand_t], reverse)
    order = torch.sort(scores, dim=1, stable=True).indices
    return to_numpy(cand_t.gather(1, order)), to_numpy(scores.gather(1, order))
