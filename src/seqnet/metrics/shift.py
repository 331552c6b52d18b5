"""Explicit positives that look shifted: the top-1 answers of the evaluated queries cluster at one constant index
offset from the listed positives (a 1-based positives file read as 0-based lists every query's reference one after
the true one, so most top-1s land exactly at positive − 1). Pure functions on arrays; the evaluation says the
line (:func:`seqnet.eval.notices.shift_notice`, which also measures a radius's top-1s from the reference nearest the
query)."""

from __future__ import annotations

import numpy as np

SHIFT_MIN = 5  # top-1s at the offset, at least
SHIFT_SHARE = 0.1  # ... and at least this share of the queries with a positive
SHIFT_RATIO = 3.0  # ... and this many times the top-1s on a listed positive, and those at the mirrored offset
SHIFT_REACH = 10  # offsets looked at, at least: within this many reference frames of the nearest listed positive


def top1_offsets(top1: np.ndarray, pos_q: np.ndarray, pos_r: np.ndarray) -> np.ndarray:
    """``[Q]`` int64: for each query with a listed positive (ascending query index), its top-1 reference frame
    minus its nearest listed positive (ties: the negative offset). ``top1 [M]``: each query's top-1 reference
    frame (< 0: none, left out); ``pos_q [P]``, ``pos_r [P]``: the (query, reference frame) pairs listed."""
    top1, pos_q, pos_r = (np.asarray(a, dtype=np.int64).ravel() for a in (top1, pos_q, pos_r))
    keep = top1[pos_q] >= 0
    q, d = pos_q[keep], top1[pos_q[keep]] - pos_r[keep]
    if len(q) == 0:
        return np.zeros(0, np.int64)
    order = np.lexsort((d, np.abs(d), q))  # by query, then |offset|, then offset (negative first)
    _, first = np.unique(q[order], return_index=True)
    return d[order][first]


def shifted_offset(offsets: np.ndarray, reach: int = SHIFT_REACH) -> int | None:
    """The nonzero offset (``|o| <= reach``, at least :data:`SHIFT_REACH`; as far as the reference route is long)
    that the top-1s of ``offsets [Q]`` (:func:`top1_offsets`, of one or several methods) cluster at, when they do:
    at least :data:`SHIFT_MIN` and :data:`SHIFT_SHARE` of them, and :data:`SHIFT_RATIO` times both the top-1s on a
    listed positive (offset 0) and those at ``-o`` (near misses of correct positives spread on both sides); None
    otherwise."""
    offsets = np.asarray(offsets, dtype=np.int64).ravel()
    reach = max(int(reach), SHIFT_REACH)
    near = offsets[np.abs(offsets) <= reach] + reach
    counts = np.bincount(near, minlength=2 * reach + 1)
    at = counts.copy()
    at[reach] = -1  # offset 0: a correct top-1
    best = int(np.argmax(at))
    o, n = best - reach, int(counts[best])
    if n < max(SHIFT_MIN, SHIFT_SHARE * len(offsets)):
        return None
    if n < SHIFT_RATIO * counts[reach] or n < SHIFT_RATIO * counts[reach - o]:
        return None
    return o
