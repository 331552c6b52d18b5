"""Re-ranking a shortlist on a memory-mapped map without reading the whole map.

For matchers whose window pairs only read the candidate's own L_m frames (fixed-speed SeqMatch,
either direction), only those frames are read from the (memory-mapped, possibly float16) frame
array, laid out window after window in a compact block, and scored there: ``M·K·L_m`` frames per
block of queries instead of the whole map. Other matchers (variable speed, graphs) read frames
outside the window, so they are scored on the whole frame array.
"""

from __future__ import annotations

import numpy as np
import torch

from ..core.utils import ArrayLike
from ..matching.hvpr import rerank

WINDOW_MATCHERS = ("seqmatch", "seqmatch-rev")  # pairs that read only the candidate window's own frames
BLOCK_BYTES = 256 * 2**20  # frames gathered per block of queries


def rerank_on_map(query_frames: ArrayLike, frames: ArrayLike, seq_len: int, q_starts: np.ndarray,
                  r_starts: np.ndarray, candidates: np.ndarray, matcher: str = "seqmatch",
                  device: str | None = None, block_bytes: int = BLOCK_BYTES,
                  window: str = "centred") -> tuple[np.ndarray, np.ndarray]:
    """:func:`seqnet.matching.hvpr.rerank` of ``candidates [M, K]`` (items, ``-1`` = none) against ``frames [Nr, D]``.

    Returns ``(scores [M, K], items [M, K])``, ascending, ties in shortlist order, as
    :func:`seqnet.matching.hvpr.rerank` on the whole array would. ``window`` (the map's window mode) sets the
    anchor of the variable-speed matchers.
    """
    cand = np.asarray(candidates, dtype=np.int64)
    if isinstance(frames, torch.Tensor):  # already in torch memory (e.g. on a GPU): score on it directly
        return rerank(query_frames, frames, seq_len, q_starts, r_starts, cand, matcher, device, window=window)
    m, k = cand.shape
    per = max(1, block_bytes // max(1, k * seq_len * frames.shape[1] * 4))
    if matcher not in WINDOW_MATCHERS or min(m, per) * k * seq_len >= len(frames):
        return rerank(query_frames, np.asarray(frames, dtype=np.float32), seq_len, q_starts, r_starts, cand,
                      matcher, device, window=window)
    scores, items = np.empty((m, k), np.float32), np.empty((m, k), np.int64)
    for s in range(0, m, per):
        scores[s : s + per], items[s : s + per] = _compact(query_frames, frames, seq_len, q_starts[s : s + per],
                                                           r_starts, cand[s : s + per], matcher, device)
    return scores, items


def _compact(query_frames: ArrayLike, frames: ArrayLike, seq_len: int, q_starts: np.ndarray, r_starts: np.ndarray,
             cand: np.ndarray, matcher: str, device: str | None) -> tuple[np.ndarray, np.ndarray]:
    """Re-rank one block on the windows of its distinct candidates, read window after window."""
    valid = cand >= 0
    uniq, inv = np.unique(cand[valid], return_inverse=True)  # distinct candidate items, sorted
    if len(uniq) == 0:  # no candidate at all: every score is inf
        return np.full(cand.shape, np.inf, np.float32), cand
    rows = (np.asarray(r_starts)[uniq][:, None] + np.arange(seq_len)).ravel()
    order = np.argsort(rows, kind="stable")  # read the memory map in increasing row order
    local = np.empty((len(rows), frames.shape[1]), np.float32)
    local[order] = np.asarray(frames[rows[order]], dtype=np.float32)
    local_cand = np.full(cand.shape, -1, np.int64)
    local_cand[valid] = inv
    sc, it = rerank(query_frames, local, seq_len, q_starts, np.arange(len(uniq)) * seq_len, local_cand, matcher,
                    device)
    return sc, np.where(it >= 0, uniq[np.clip(it, 0, None)], -1)
