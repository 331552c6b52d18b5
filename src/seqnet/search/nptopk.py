"""Top-k in numpy, with the semantics of :func:`seqnet.search.blocks.topk_smallest` (no torch needed).

The ``k`` smallest entries of each row, ascending, ties broken by the lower column (also at the
cut-off), NaN ranked as +inf: the answer of a stable argsort. One ``argpartition`` selects a candidate
set; only the rows whose k-th value is tied with a value left out (or is not finite) are sorted whole.
:func:`merge_topk_np` folds a later block of columns into a running top-k (the earlier columns first, so
ties keep the lower column).
"""

from __future__ import annotations

from collections.abc import Callable

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


STRIDES = 256  # columns per stride of :func:`merge_smallest`'s bound (at least k of them)


def merge_smallest(best: tuple[np.ndarray, np.ndarray] | None, x: np.ndarray, offset: int,
                   k: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`merge_topk_np` (the same answer: lowest value, then lowest column; NaN as +inf) by a bound instead
    of a partition of every row: the ``k``-th smallest of the minima of ``x``'s strided column groups (columns
    ``j, j + m, j + 2m, ...``: neighbours on a route fall in different groups) bounds each row's k-th value from
    above, so the entries at or under it hold the row's top k, ties at the cut-off included; only those are
    sorted. Rows whose bound is not finite, and blocks too narrow for ``k`` groups, take :func:`merge_topk_np`."""
    k = _capped(best, x, k)
    if not _boundable(best, x, k):
        return merge_topk_np(best, x, offset, k)
    bound = _group_bound(x, k)
    if best is not None:
        bound = np.minimum(bound, best[0][:, k - 1])  # the running k-th: nothing over it can enter
    return _merge_under(best, x, offset, k, bound, bound, lambda v, rows: v, lambda rows: x[rows])


def finished(u: np.ndarray, add: np.ndarray) -> np.ndarray:
    """``sqrt(max(u + add[:, None], 0))`` of ``u [B, c]``, ``add [B]`` (distances from ``‖r‖² − 2 q·r`` and
    ``‖q‖²``), in ``u``'s dtype, in that order of operations."""
    v = u + add[:, None]
    return np.sqrt(np.maximum(v, 0, out=v), out=v)


def merge_distances(best: tuple[np.ndarray, np.ndarray] | None, u: np.ndarray, add: np.ndarray, offset: int,
                    k: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`merge_smallest` of the distances ``finished(u, add)`` (``[B, c]``) with only the candidates finished:
    the group bound is taken on ``u`` and finished, and the entries of ``u`` under the generous inverse of the
    running k-th distance (:func:`_u_threshold`: every entry whose finished distance could be at or under it)
    are finished, sorted and merged. The answer is that of ``merge_smallest(best, finished(u, add), ...)``."""
    k = _capped(best, u, k)
    if not _boundable(best, u, k):
        return merge_smallest(best, finished(u, add), offset, k)
    vb = finished(_group_bound(u, k)[:, None], add)[:, 0]  # k entries finish at or under it
    if best is not None:
        vb = np.minimum(vb, best[0][:, k - 1])
    return _merge_under(best, u, offset, k, vb, _u_threshold(vb, add, u.dtype),
                        lambda v, rows: np.sqrt(np.maximum(v + add[rows], 0)),
                        lambda rows: finished(u[rows], add[rows]))


def _capped(best: tuple[np.ndarray, np.ndarray] | None, x: np.ndarray, k: int) -> int:
    """``k`` capped at the columns seen so far."""
    return min(int(k), x.shape[1] + (0 if best is None else best[0].shape[1]))


def _boundable(best: tuple[np.ndarray, np.ndarray] | None, x: np.ndarray, k: int) -> bool:
    """Whether the group bound applies: float rows, at least ``k`` groups, a running top-k of ``k``."""
    b, c = x.shape
    return b > 0 and k > 0 and min(STRIDES, c) >= k and x.dtype.kind == "f" and (best is None or best[0].shape[1] >= k)


def _group_bound(x: np.ndarray, k: int) -> np.ndarray:
    """``[B]``: the k-th smallest of the minima of ``x``'s strided column groups (at least k entries under it)."""
    b, c = x.shape
    m = min(STRIDES, c)
    w = c // m
    return np.partition(x[:, : w * m].reshape(b, w, m).min(1), k - 1, axis=1)[:, k - 1]


def _u_threshold(v: np.ndarray, add: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """``[B]`` in ``dtype``: a value of ``u`` at or over every ``u`` whose ``finished(u, add)`` is at or under ``v``
    (the square of ``v`` two units in the last place up, less ``add``, with a margin for the addition's rounding;
    rounded up). Generous: more candidates, never fewer."""
    eps = float(np.finfo(dtype).eps)
    v64 = v.astype(np.float64)
    t = (v64 + 2 * np.spacing(v.astype(dtype)).astype(np.float64)) ** 2 * (1 + 4 * eps) - add
    t = t + 4 * eps * (np.abs(t) + np.abs(add))
    return np.nextafter(t.astype(dtype), np.inf)


def _merge_under(best: tuple[np.ndarray, np.ndarray] | None, x: np.ndarray, offset: int, k: int,
                 bound: np.ndarray, cut: np.ndarray, value: Callable, whole: Callable) -> tuple[np.ndarray, np.ndarray]:
    """The merge of :func:`merge_smallest`: the entries of ``x`` at or under ``cut`` (per row) become values
    (``value(entries, rows)``), are sorted with ``best`` by row, value, column, and the first ``k`` of each row
    kept. Rows whose ``bound`` is not finite take :func:`merge_topk_np` of ``whole(rows)`` (their values)."""
    b, c = x.shape
    odd = ~np.isfinite(bound)  # NaN or inf in the bound: the whole row, by sort
    cut = np.where(odd, -np.inf, cut) if odd.any() else cut  # no candidates taken from those rows here
    flat = np.flatnonzero(x <= cut[:, None])
    rows, cols = np.divmod(flat, c)
    vals = value(x.ravel()[flat] if x.flags.c_contiguous else x[rows, cols], rows)
    cols = cols + offset
    if best is not None:  # the earlier columns first: a stable sort keeps them ahead of a tie
        rows = np.concatenate([np.repeat(np.arange(b), best[0].shape[1]), rows])
        vals = np.concatenate([best[0].ravel(), vals.astype(best[0].dtype, copy=False)])
        cols = np.concatenate([best[1].ravel(), cols])
    order = np.lexsort((vals, rows))  # by row, then value; stable: ties keep the lower column
    counts = np.bincount(rows, minlength=b)
    pick = (np.cumsum(counts) - counts)[:, None] + np.arange(k)
    out_v, out_i = np.empty((b, k), vals.dtype), np.empty((b, k), np.int64)
    good = ~odd
    if good.any():
        out_v[good], out_i[good] = vals[order][pick[good]], cols[order][pick[good]]
    if odd.any():
        sub = None if best is None else (best[0][odd], best[1][odd])
        out_v[odd], out_i[odd] = merge_topk_np(sub, whole(np.flatnonzero(odd)), offset, k)
    return out_v, out_i
