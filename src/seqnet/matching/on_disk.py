"""Scoring a shortlist on memory-mapped frames (a map, a spilled reference) without reading them all.

For matchers whose window pairs only read the candidate's own L_m frames (fixed-speed SeqMatch,
either direction), only those frames are read from the (memory-mapped, possibly float16) frame
array, laid out window after window in a compact block, and scored there: ``M·K·L_m`` frames per
block of queries instead of the whole map. Other matchers (variable speed, graphs) read frames
outside the window, so they are scored on the whole frame array.
"""

from __future__ import annotations

import numpy as np

from ..core.lazy import lazy_module
from ..core.memmaps import take_rows
from ..core.memory import BLOCK_BYTES as MEMORY_BLOCK
from ..core.tensors import ArrayLike
from .hvpr import pair_scores
from .registry import SEQUENCE_MATCHERS

torch = lazy_module("torch")

BLOCK_BYTES = 4 * MEMORY_BLOCK  # frames gathered per block of queries


def pair_scores_on_map(query_frames: ArrayLike, frames: ArrayLike, seq_len: int, q_starts: np.ndarray,
                       r_starts: np.ndarray, candidates: np.ndarray, matcher: str = "seqmatch",
                       device: str | None = None, block_bytes: int = BLOCK_BYTES,
                       anchor: str = "centre") -> torch.Tensor:
    """:func:`seqnet.matching.hvpr.pair_scores` of ``candidates [M, K]`` (items, ``-1`` = none) against
    ``frames [Nr, D]``: the same ``[M, K]`` scores, in candidate order, read window by window."""
    cand = np.asarray(candidates, dtype=np.int64)
    if isinstance(frames, torch.Tensor):  # already in torch memory (e.g. on a GPU): score on it directly
        return pair_scores(query_frames, frames, seq_len, q_starts, r_starts, cand, matcher, device, anchor)
    m, k = cand.shape
    per = max(1, block_bytes // max(1, k * seq_len * frames.shape[1] * 4))
    if not SEQUENCE_MATCHERS[matcher].diagonal or min(m, per) * k * seq_len >= len(frames):
        return pair_scores(query_frames, np.asarray(frames, dtype=np.float32), seq_len, q_starts, r_starts, cand,
                           matcher, device, anchor)
    blocks = [_compact(query_frames, frames, seq_len, q_starts[s : s + per], r_starts, cand[s : s + per], matcher,
                       device) for s in range(0, m, per)]
    return torch.cat(blocks) if blocks else torch.zeros((0, k))


def _compact(query_frames: ArrayLike, frames: ArrayLike, seq_len: int, q_starts: np.ndarray, r_starts: np.ndarray,
             cand: np.ndarray, matcher: str, device: str | None) -> torch.Tensor:
    """Score one block on the windows of its distinct candidates, read window after window."""
    valid = cand >= 0
    uniq, inv = np.unique(cand[valid], return_inverse=True)  # distinct candidate items, sorted
    if len(uniq) == 0:  # no candidate at all: every score is inf
        return torch.full(cand.shape, float("inf"))
    rows = (np.asarray(r_starts)[uniq][:, None] + np.arange(seq_len)).ravel()
    order = np.argsort(rows, kind="stable")  # read the memory map in increasing row order
    local = np.empty((len(rows), frames.shape[1]), np.float32)
    local[order] = take_rows(frames, rows[order])
    local_cand = np.full(cand.shape, -1, np.int64)
    local_cand[valid] = inv
    return pair_scores(query_frames, local, seq_len, q_starts, np.arange(len(uniq)) * seq_len, local_cand, matcher,
                       device)
