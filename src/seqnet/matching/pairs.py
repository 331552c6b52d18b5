"""SeqMatch scores of given (query window, reference window) pairs, e.g. an HVPR shortlist.

Two ways to compute ``Σ_t ‖q[a+t] − r[b+t]‖`` for K candidate windows b of each query window a:

* ``gather``: the L frame differences of every pair (``M·K·L·D`` work, no matter how large the
  map): cheap when the shortlist is small next to the map;
* ``rows``: the distance rows of the query frames against the whole map (one GEMM per block of
  queries, ``≈ M·N_db·D``) and a gather of the L entries of each pair: cheap when the map is small
  next to ``K·L`` (a GEMM does a multiply-add an order of magnitude faster than a gathered
  difference), and never costlier than whole-map SeqMatch, which needs the same rows.

``strategy="auto"`` picks the cheaper by that count (:func:`pick_strategy`).
"""

from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError
from ..core.lazy import lazy_module
from ..search.blocks import topk_smallest
from ..search.knn import finish_distances, rows_per_block, sq_norms

torch = lazy_module("torch")

STRATEGIES = ("auto", "gather", "rows")
# the fixed-speed matchers: a window pair reads only the candidate window's own frames, summed along a
# (reverse: anti-) diagonal of the frame-distance matrix; matcher -> reverse
GEMM_ADVANTAGE = 16  # a GEMM multiply-add is about this many times cheaper than a gathered difference


def pick_strategy(n_queries: int, n_candidates: int, seq_len: int, n_ref: int) -> str:
    """``"rows"`` when the distance rows cost less than gathering every pair's frames, else ``"gather"``."""
    gather = n_queries * n_candidates * seq_len * GEMM_ADVANTAGE
    rows = (n_queries + seq_len) * n_ref
    return "rows" if rows < gather else "gather"


def window_scores(
    q: torch.Tensor,
    r: torch.Tensor,
    seq_len: int,
    q_starts: torch.Tensor,
    cand: torch.Tensor,
    reverse: bool = False,
    block_bytes: int | None = None,
    strategy: str = "auto",
) -> torch.Tensor:
    """SeqMatch scores of given window pairs: query windows ``q_starts [M]`` vs ``cand [M, K]``.

    Returns ``[M, K]``; candidates equal to -1 score ``inf``. Validates the index ranges.
    """
    cand, q_starts = _check(q, r, seq_len, q_starts.long(), cand.long())
    if strategy not in STRATEGIES:
        raise ConfigError(f"unknown re-ranking strategy {strategy!r}; valid: {', '.join(STRATEGIES)}")
    m, k = cand.shape
    if strategy == "auto":
        strategy = pick_strategy(m, k, seq_len, r.shape[0])
    missing = cand < 0
    fn = _by_rows if strategy == "rows" else _by_gather
    out = fn(q, r, seq_len, q_starts, cand.clamp_min(0), reverse, block_bytes)
    return out.masked_fill_(missing, float("inf"))


def _check(q: torch.Tensor, r: torch.Tensor, seq_len: int, q_starts: torch.Tensor,
           cand: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    nb = r.shape[0] - seq_len + 1
    if cand.ndim != 2 or q_starts.ndim != 1 or cand.shape[0] != q_starts.shape[0]:
        raise ConfigError(
            f"window pairs need query starts [M] and candidates [M, K], got {tuple(q_starts.shape)} "
            f"and {tuple(cand.shape)}"
        )
    if cand.numel() and (cand.min() < -1 or cand.max() >= nb):
        raise ConfigError(f"candidate window starts must lie in 0..{nb - 1} (or -1 for none)")
    if q_starts.numel() and (q_starts.min() < 0 or q_starts.max() > q.shape[0] - seq_len):
        raise ConfigError(f"query window starts must lie in 0..{q.shape[0] - seq_len}")
    return cand, q_starts


def _by_gather(q: torch.Tensor, r: torch.Tensor, seq_len: int, q_starts: torch.Tensor, cand: torch.Tensor,
               reverse: bool, block_bytes: int | None) -> torch.Tensor:
    m, k = cand.shape
    out = torch.zeros((m, k), dtype=q.dtype, device=q.device)
    rows = rows_per_block(max(1, k) * q.shape[1] * q.element_size() * 2, block_bytes)
    for s in range(0, m, rows):
        qs, cs = q_starts[s : s + rows], cand[s : s + rows]
        for t in range(seq_len):
            rt = seq_len - 1 - t if reverse else t
            diff = r[cs + rt] - q[qs + t][:, None, :]
            out[s : s + rows] += diff.norm(dim=-1)
    return out


def _by_rows(q: torch.Tensor, r: torch.Tensor, seq_len: int, q_starts: torch.Tensor, cand: torch.Tensor,
             reverse: bool, block_bytes: int | None) -> torch.Tensor:
    """Distance rows of the query frames in use (blocks of queries sorted by start), then gathers."""
    m, k = cand.shape
    out = torch.zeros((m, k), dtype=q.dtype, device=q.device)
    order = torch.argsort(q_starts, stable=True)
    r_sq = sq_norms(r)
    step = rows_per_block(r.shape[0] * q.element_size() * 2, block_bytes)
    shifts = torch.arange(seq_len, device=q.device)
    ref_shift = shifts.flip(0) if reverse else shifts
    s = 0
    while s < m:
        sel = order[s : s + step]
        a0 = int(q_starts[sel[0]])
        sel = sel[q_starts[sel] < a0 + step]  # queries whose frames fit this block of rows
        frames = q[a0 : int(q_starts[sel[-1]]) + seq_len]
        dist = finish_distances(frames @ r.T, sq_norms(frames), r_sq)  # [n + L - 1, Nr]
        out[sel] = gather_sums(dist, q_starts[sel] - a0, cand[sel], shifts, ref_shift)
        s += len(sel)
    return out


def gather_sums(dist: torch.Tensor, rows: torch.Tensor, cols: torch.Tensor, shifts: torch.Tensor,
                ref_shift: torch.Tensor) -> torch.Tensor:
    """``[b, K]``: ``Σ_t dist[rows[i] + shifts[t], cols[i, j] + ref_shift[t]]`` (window starts ``rows [b]``,
    ``cols [b, K]`` into a frame-distance matrix ``dist``)."""
    return dist[rows[:, None, None] + shifts, cols[:, :, None] + ref_shift].sum(-1)


def item_starts(candidates: np.ndarray | torch.Tensor, r_starts: torch.Tensor) -> torch.Tensor:
    """``[M, K]`` window starts of candidate items ``[M, K]`` (``-1``: none stays ``-1``) whose starts are
    ``r_starts [R]``."""
    cand = torch.as_tensor(candidates, device=r_starts.device).long()
    return torch.where(cand >= 0, r_starts[cand.clamp_min(0)], -1) if len(r_starts) else cand


def item_scores_from_distances(dist: torch.Tensor, seq_len: int, q_starts: torch.Tensor, r_starts: torch.Tensor,
                               candidates: np.ndarray | torch.Tensor, reverse: bool) -> torch.Tensor:
    """:func:`scores_from_distances` of candidate *items* ``[M, K]`` (``-1``: none) with window starts
    ``r_starts [R]``, for a diagonal matcher (``SequenceMatcher.diagonal``; ``reverse``: its direction)."""
    return scores_from_distances(dist, seq_len, q_starts, item_starts(candidates, r_starts), reverse)


def nearest_items(dist: torch.Tensor, q_rows: np.ndarray | torch.Tensor, r_items: np.ndarray,
                  k: int) -> tuple[np.ndarray, np.ndarray]:
    """``(distances [M, k], items [M, k])``: the k items (frames ``r_items [R]``) nearest to the query frames
    ``q_rows [M]``, read from the frame-distance matrix ``dist``."""
    rows = torch.as_tensor(q_rows, device=dist.device).long()
    vals, idx = topk_smallest(dist[rows][:, torch.as_tensor(r_items, device=dist.device)], k)
    return vals.cpu().numpy(), idx.cpu().numpy()


def scores_from_distances(dist: torch.Tensor, seq_len: int, q_starts: torch.Tensor, cand: torch.Tensor,
                          reverse: bool = False) -> torch.Tensor:
    """SeqMatch scores ``[M, K]`` of the windows ``q_starts [M]`` × ``cand [M, K]`` (starts, ``-1``: none, inf)
    read from a precomputed frame-distance matrix ``dist [Nq, Nr]`` (e.g. computed once for an HVPR shortlist)."""
    q_starts, cand = q_starts.long(), cand.long()
    if cand.numel() and (int(cand.max()) > dist.shape[1] - seq_len or int(q_starts.max()) > dist.shape[0] - seq_len):
        raise ConfigError(f"window starts must leave {seq_len} frames inside the {tuple(dist.shape)} distance matrix")
    shifts = torch.arange(seq_len, device=dist.device)
    out = gather_sums(dist, q_starts, cand.clamp_min(0), shifts, shifts.flip(0) if reverse else shifts)
    return out.masked_fill_(cand < 0, float("inf"))
