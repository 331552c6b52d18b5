"""Top-k in numpy, with the semantics of :func:`seqnet.search.blocks.topk_smallest` (no torch needed).

The ``k`` smallest entries of each row, ascending, ties broken by the lower column (also at the
cut-off), NaN ranked as +inf: the answer of a stable argsort. One ``argpartition`` selects a candidate
set; only the rows whose k-th value is tied with a value left out (or is not finite) are sorted whole.
:func:`merge_topk_np` folds a later block of columns into a running top-k (the earlier columns first, so
ties keep the lower column).
"""

from __future__ import annotations

import numpy as np


def _key(x: np.ndarray) -> np.ndarray:
    """``x`` with NaN as +inf (a copy only when ``x`` holds NaN)."""
    if x.dtype.kind == "f" and np.isnan(x).any():
        return np.where(np.isnan(x), np.inf, x)
    return x


def _ordered(key: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``idx [B, m]`` reordered by (value of ``key``, column): sorted by column, then stably by value."""
    idx = np.sort(idx, axis=1)
    vals = np.take_along_axis(key, idx, 1)
    return np.take_along_axis(idx, np.argsort(vals, axis=1, kind="stable"), 1)


def topk_smallest_np(x: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """``(values [B, k], columns [B, k])``: the ``k`` smallest of each row of ``x [B, N]``, ascending, ties by
    the lower column, NaN as +inf (``k`` capped at N); values in ``x``'s dtype."""
    b, n = x.shape
    k = min(int(k), n)
    if k <= 0 or b == 0:
        return np.zeros((b, max(k, 0)), x.dtype), np.zeros((b, max(k, 0)), np.int64)
    key = _key(x)
    if k == 1:
        idx = np.argmin(key, axis=1)[:, None]  # argmin: the first of the smallest
    elif k == n or n <= 64:
        idx = np.argsort(key, axis=1, kind="stable")[:, :k]
    else:
        part = np.argpartition(key, k - 1, axis=1)[:, :k]
        kth = np.take_along_axis(key, part, 1).max(1)
        idx = _ordered(key, part)
        redo = np.flatnonzero((np.count_nonzero(key <= kth[:, None], axis=1) > k) | ~np.isfinite(kth))
        if len(redo):  # a cut-off inside a run of ties (or an inf in the selection): a stable sort of the row
            idx[redo] = np.argsort(key[redo], axis=1, kind="stable")[:, :k]
    return np.take_along_axis(x, idx, 1), idx.astype(np.int64, copy=False)


def merge_topk_np(best: tuple[np.ndarray, np.ndarray] | None, x: np.ndarray, offset: int,
                  k: int) -> tuple[np.ndarray, np.ndarray]:
    """Fold the block ``x [B, c]`` of columns ``offset .. offset + c - 1`` (after every column in ``best``) into
    the running ``(values [B, k'], columns [B, k'])``."""
    v, i = topk_smallest_np(x, k)
    i = i + offset
    if best is None:
        return v, i
    vals, idx = np.concatenate([best[0], v], 1), np.concatenate([best[1], i], 1)
    order = np.argsort(_key(vals), axis=1, kind="stable")[:, :k]  # the earlier columns come first: ties stay
    return np.take_along_axis(vals, order, 1), np.take_along_axis(idx, order, 1)
