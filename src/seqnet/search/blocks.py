"""Memory-bounded search: blocks over both the query and the reference side, and a running top-K.

Whole-map searches (k-NN, SeqMatch) never hold an ``N_q × N_db`` score matrix, nor the whole map
in torch memory: the query is cut into row blocks, the reference into column blocks read straight
from the (possibly memory-mapped, possibly float16) array, and each row block keeps only its k best
columns so far (faiss ``knn_ground_truth`` style). Blocks visit columns in increasing order and
ties keep the lower column, so the result equals a top-k over the whole row.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import Any

import numpy as np

from ..core.errors import ConfigError
from ..core.lazy import lazy_module, no_grad
from ..core.memmaps import read_rows
from ..core.memory import BLOCK_BYTES as MEMORY_BLOCK
from ..core.tensors import ArrayLike, as_tensor

FINITE_HINT = "hint: drop or recompute rows that hold NaN or inf; L2-normalise rows of large values"

torch = lazy_module("torch")

SORT_MAX = 2048  # up to this many scores a stable sort is quicker than topk + tie check (the same result)
COL_BLOCK_BYTES = MEMORY_BLOCK // 2  # reference bytes per column block (between 1,024 and 65,536 rows)


def matrix_shape(x: ArrayLike, name: str) -> tuple[int, int]:
    """``(N, D)`` of a 2-D numeric array or tensor, checked without reading it."""
    if not isinstance(x, (np.ndarray, torch.Tensor)):
        x = np.asarray(x)
    kind = "f" if isinstance(x, torch.Tensor) and x.is_floating_point() else getattr(x.dtype, "kind", "")
    if x.ndim != 2:
        raise ConfigError(f"{name} must be a [N, D] matrix, got shape {tuple(x.shape)}")
    if isinstance(x, np.ndarray) and kind not in "fiub":
        raise ConfigError(f"{name} must hold numbers, got dtype {x.dtype}")
    return int(x.shape[0]), int(x.shape[1])


def rows(x: ArrayLike, a: int, b: int, device: torch.device, dtype: torch.dtype) -> torch.Tensor:
    """Rows ``a:b`` of ``x`` as a ``dtype`` tensor on ``device`` (only those rows are read from a memory map;
    a streamed map's pages are released after: :func:`seqnet.core.memmaps.read_rows`)."""
    block = x[a:b] if isinstance(x, torch.Tensor) else read_rows(x, a, b)
    if dtype == torch.float16 and isinstance(block, np.ndarray) and block.dtype == np.float16 and block.flags.writeable:
        return torch.from_numpy(np.ascontiguousarray(block)).to(device)  # a float16 map read as it is stored
    return as_tensor(block, device, keep_float64=True).to(dtype)


def check_pair_dims(query: ArrayLike, ref: ArrayLike) -> tuple[int, int, int]:
    """``(Nq, Nr, D)``; :class:`ConfigError` when the descriptor dimensions differ."""
    nq, dq = matrix_shape(query, "query")
    nr, dr = matrix_shape(ref, "reference")
    if dq != dr:
        raise ConfigError(f"dimension mismatch: query D={dq}, reference D={dr}")
    return nq, nr, dq


def _exact_ties(key: torch.Tensor, k: int) -> torch.Tensor:
    """Columns ``[B, k]`` of the ``k`` smallest of ``key [B, N]`` (no NaN) by (value, column): every entry tied
    with the k-th value counted (the rows whose cut-off falls inside a run of ties)."""
    kth = torch.topk(key, k, dim=1, largest=False, sorted=True).values[:, -1:]
    less, ties = key < kth, key == kth
    keep = less | (ties & (ties.cumsum(1) <= k - less.sum(1, keepdim=True)))
    return keep.nonzero()[:, 1].reshape(key.shape[0], k)  # ascending column order


def _canonical(vals: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """``idx [B, m]`` reordered by (value, column): a sort by column, then a stable sort by value."""
    by_col = torch.sort(idx, dim=1).indices
    vals, idx = vals.gather(1, by_col), idx.gather(1, by_col)
    return idx.gather(1, torch.sort(vals, dim=1, stable=True).indices)


def topk_smallest(scores: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The ``k`` smallest entries of each row of ``scores [B, N]``, ascending.

    Ties are broken deterministically by the lower column index (also at the cut-off); NaN ranks
    like +inf. Returns ``(values [B, k], indices [B, k])``; ``k`` is capped at N. The answer is a
    stable argsort's; it costs one ``topk`` of ``k + 1`` over the scores: only the rows whose k-th
    value is tied with the next one (or is not finite) are counted again over the whole row.
    """
    k = min(int(k), scores.shape[1])
    if k <= 0 or scores.shape[0] == 0:
        empty = scores.new_zeros((scores.shape[0], max(k, 0)))
        return empty, empty.long()
    floating = scores.is_floating_point()
    if scores.shape[0] * scores.shape[1] <= SORT_MAX:  # a short row (a frame of a stream): one stable sort
        key = scores.masked_fill(torch.isnan(scores), float("inf")) if floating else scores
        idx = torch.sort(key, dim=1, stable=True).indices[:, :k]
        return scores.gather(1, idx), idx
    kk = min(k + 1, scores.shape[1])
    v, i = torch.topk(scores, kk, dim=1, largest=False, sorted=True)  # NaN last, as +inf would be
    idx = _canonical(v, i)
    v = scores.gather(1, idx)
    redo = ~torch.isfinite(v[:, k - 1]) if floating else torch.zeros_like(v[:, 0], dtype=torch.bool)
    if kk > k:
        redo |= v[:, k] == v[:, k - 1]
    idx = idx[:, :k]
    rows = redo.nonzero()[:, 0]
    if len(rows):  # a cut-off inside a run of ties, or inf / NaN in the selection: count the whole row
        key = scores[rows]
        key = key.masked_fill(torch.isnan(key), float("inf")) if floating else key
        sel = _exact_ties(key, k)
        idx[rows] = _canonical(key.gather(1, sel), sel)
    return scores.gather(1, idx), idx


def merge_topk(best: tuple[torch.Tensor, torch.Tensor] | None, scores: torch.Tensor, cols: torch.Tensor | None,
               k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Fold a block ``scores [n, c]`` of columns ``cols [c]`` (increasing, after every column in ``best``;
    None: columns ``0 .. c-1``) into the running ``(values [n, k'], columns [n, k'])`` (faiss
    ``ResultHeap`` style; no host sync)."""
    if best is None:
        v, i = topk_smallest(scores, k)
        return v, cols[i] if cols is not None and cols.numel() else i
    vals, idx = best
    bv, bi = topk_smallest(scores, k)  # the block's own best (ties by column), then the two short lists:
    bi = cols[bi] if cols is not None and cols.numel() else bi  # the earlier columns first, so ties stay by column
    v, i = topk_smallest(torch.cat([vals, bv], dim=1), k)
    return v, torch.cat([idx, bi], dim=1).gather(1, i)


RowBlock = tuple[Any, Any]  # (rows of the output this block fills: a slice or an index array, the block's context)
ScoreFn = Callable[[Any, Any], tuple["torch.Tensor", "torch.Tensor"]]  # (context, column block) -> (scores, columns)


@no_grad
def blocked_topk(row_blocks: Iterable[RowBlock], col_blocks: Sequence[Any], score: ScoreFn, n_rows: int, k: int,
                 dtype: torch.dtype, finite: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The one blocked-search driver: query row blocks × reference column blocks, top-k merged on the fly.

    ``score(context, col_block)`` returns ``(scores [n, c], columns [c])`` of one block; columns are
    visited in increasing order, so ties keep the lower column (the result equals a top-k over the
    whole row). With ``finite``, a NaN or inf score is a :class:`ConfigError`, checked once at the
    end (no host sync per block). Returns ``(values [n_rows, k], columns [n_rows, k])`` as numpy.
    """
    done: list[tuple[Any, torch.Tensor, torch.Tensor]] = []
    bad = None
    for sel, ctx in row_blocks:
        best = None
        for cb in col_blocks:
            scores, cols = score(ctx, cb)
            if finite:
                flag = ~torch.isfinite(scores).all()
                bad = flag if bad is None else bad | flag
            best = merge_topk(best, scores, cols, k)
        if best is not None:
            done.append((sel, best[0].cpu(), best[1].cpu()))
    if bad is not None and bool(bad):
        raise ConfigError("the distances are not finite: the descriptors hold NaN or inf, or values too large "
                          f"for {str(dtype).removeprefix('torch.')} ({FINITE_HINT})")
    if len(done) == 1 and done[0][0] == slice(0, n_rows):  # one block of every row, in order
        return done[0][1].numpy(), done[0][2].numpy()
    vals, idx = torch.zeros((n_rows, k), dtype=dtype), torch.zeros((n_rows, k), dtype=torch.long)
    for sel, v, i in done:
        vals[sel], idx[sel] = v, i
    return vals.numpy(), idx.numpy()


def col_blocks(n: int, col_block: int | None, row_bytes: int = 4096) -> list[tuple[int, int]]:
    """``[(c0, c1), ...]`` covering ``range(n)`` in blocks of ``col_block`` rows (default: rows of ``row_bytes``
    bytes filling :data:`COL_BLOCK_BYTES`, between 1,024 and 65,536)."""
    size = max(1, col_block or min(65536, max(1024, COL_BLOCK_BYTES // max(1, row_bytes))))
    return [(c, min(n, c + size)) for c in range(0, n, size)]
