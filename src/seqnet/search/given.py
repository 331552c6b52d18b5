"""A given ``[Nq, Nr]`` distance or similarity matrix read in its own dtype, block by block (no torch, no copy).

``seqnet eval --distances`` reads a matrix another tool made (VPR-Bench, VPR_Tutorial): often a
similarity (higher is closer), often one row per reference (``--transposed``), often float16 or float32,
and as large as the memory. :class:`GivenMatrix` is the distances ``sign * raw`` (``raw.T`` when
transposed) over the file's (memory-mapped) array ``raw`` without making them: one pass over blocks
of the file's rows (:meth:`GivenMatrix.scan`) gives every query's k nearest references (values as
float64, ties by the lower reference, as :func:`seqnet.search.blocks.topk_smallest` breaks them), the
other readings' best matches (for the orientation check), and checks every entry is finite. The
values are those of the float64 matrix (float16 / float32 widen exactly), so the answers equal a top-k
of the dense float64 distances (:meth:`GivenMatrix.dense`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.errors import DatasetError
from ..core.memmaps import read_rows
from .nptopk import merge_topk_np, topk_smallest_np

SCAN_BYTES = 4 << 20  # file bytes per block of a scan (a few passes over it stay in the cache)


@dataclass
class Scan:
    """What one pass over a :class:`GivenMatrix` found: ``topk`` ``(values [Nq, k] float64, references
    [Nq, k])`` of the distances; ``best`` the index of each reading's best match per query:
    ``"as given"`` / ``"other sense"`` (argmin / argmax of a row, the first on ties) and, when square,
    ``"transposed"`` / ``"transposed, other sense"`` (of the column)."""

    topk: tuple[np.ndarray, np.ndarray]
    best: dict[str, np.ndarray]


@dataclass
class GivenMatrix:
    """The distances ``[Nq, Nr]``: ``raw`` (``[Nq, Nr]``, or ``[Nr, Nq]`` when ``transposed``), negated when
    ``negate`` (a similarity), in ``raw``'s dtype; ``where``: the file, for errors."""

    raw: np.ndarray
    negate: bool = False
    transposed: bool = False
    where: str = "the matrix"
    unchecked: bool = False  # finiteness left to the first scan (which checks every entry it reads)
    _scans: dict[int, Scan] = field(default_factory=dict, repr=False)

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.raw.shape[::-1]) if self.transposed else tuple(self.raw.shape)  # type: ignore[return-value]

    @property
    def ndim(self) -> int:
        return 2

    def _finish(self, block: np.ndarray) -> np.ndarray:
        """A block of ``raw`` as float64 distances (a copy)."""
        out = np.array(block, dtype=np.float64)
        return np.negative(out, out=out) if self.negate else out

    def dense(self) -> np.ndarray:
        """``[Nq, Nr]`` float64 distances (the whole matrix in memory: what the torch methods read)."""
        out = self._finish(self.raw)
        return np.ascontiguousarray(out.T) if self.transposed else out

    def block(self, q: slice, r: slice) -> GivenMatrix:
        """The query rows ``q`` and reference columns ``r`` as a matrix of their own: a view of ``raw`` (nothing
        read or copied) with the same reading."""
        raw = self.raw[r, q] if self.transposed else self.raw[q, r]
        return GivenMatrix(raw, self.negate, self.transposed, self.where, self.unchecked)

    def __getitem__(self, key: tuple[Any, Any]) -> np.ndarray:
        """Float64 distances of ``dense()[key]`` for a ``(rows, columns)`` key (``np.ix_``, slices, indices),
        reading only those entries."""
        q, r = key
        if not self.transposed:
            return self._finish(self.raw[q, r])
        q, r = (x.T if isinstance(x, np.ndarray) else x for x in (q, r))
        return self._finish(self.raw[r, q]).T

    def scan(self, k: int) -> Scan:
        """One pass over blocks of the file's rows (made once per ``k``); a non-finite entry is a
        :class:`DatasetError` naming it (row and column of the file)."""
        if k not in self._scans:
            self._scans[k] = self._scan(k)
        return self._scans[k]

    def best(self) -> dict[str, np.ndarray]:
        """:attr:`Scan.best` of a scan made already (any k), else of a new one (k = 1)."""
        return next(iter(self._scans.values())).best if self._scans else self.scan(1).best

    def _scan(self, k: int) -> Scan:
        n, m = self.raw.shape
        square = n == m
        step = max(1, SCAN_BYTES // max(1, m * self.raw.itemsize))
        amin, amax, cmin, cmax = [], [], None, None
        best_k = None
        rows_k = []
        for a in range(0, n, step):
            block = read_rows(self.raw, a, min(n, a + step))
            if block.dtype.kind not in "f" or block.dtype.itemsize > 8:
                block = np.asarray(block, np.float64)  # integers: compared as the float64 matrix would
            lo, hi = block.argmin(1), block.argmax(1)
            ar = np.arange(len(block))
            if not (np.isfinite(block[ar, lo]).all() and np.isfinite(block[ar, hi]).all()):
                self._refuse(block, a)
            amin.append(lo)
            amax.append(hi)
            if self.transposed or square:
                cmin, cmax = _fold_cols(cmin, block, a, np.less), _fold_cols(cmax, block, a, np.greater)
            if k > 1:
                sign = -block if self.negate else block
                if self.transposed:
                    best_k = merge_topk_np(best_k, np.ascontiguousarray(sign.T), a, k)
                else:
                    rows_k.append(topk_smallest_np(sign, k)[1])
        rmin = np.concatenate(amin) if amin else np.zeros(0, np.int64)
        rmax = np.concatenate(amax) if amax else np.zeros(0, np.int64)
        low, high = (rmax, rmin) if self.negate else (rmin, rmax)  # a similarity's best is its largest
        cols = (cmax[1], cmin[1]) if self.negate and cmin else ((cmin[1], cmax[1]) if cmin else None)
        best = {"as given": low, "other sense": high}
        if self.transposed:
            best = {"as given": cols[0], "other sense": cols[1]}
            if square:
                best |= {"transposed": low, "transposed, other sense": high}
        elif square:
            best |= {"transposed": cols[0], "transposed, other sense": cols[1]}
        nq, nr = self.shape
        if k == 1 or nr == 0:
            idx = best["as given"][:, None] if nr else np.zeros((nq, 0), np.int64)
        else:
            idx = best_k[1] if self.transposed else np.concatenate(rows_k)
        idx = idx.astype(np.int64, copy=False)
        return Scan((self._values(idx), idx), {key: v.astype(np.int64, copy=False) for key, v in best.items()})

    def _values(self, idx: np.ndarray) -> np.ndarray:
        """``[Nq, k]`` float64 distances of the references ``idx`` of every query."""
        q = np.arange(idx.shape[0])[:, None]
        raw = self.raw[idx, q] if self.transposed else self.raw[q, idx]
        return self._finish(raw)

    def _refuse(self, block: np.ndarray, a: int) -> None:
        r, c = np.argwhere(~np.isfinite(block))[0]
        raise DatasetError(f"{self.where}: entry [{r + a}, {c}] is {block[r, c]} (every entry must be "
                           "finite)")


def _fold_cols(run: tuple[np.ndarray, np.ndarray] | None, block: np.ndarray, a: int,
               better: np.ufunc) -> tuple[np.ndarray, np.ndarray]:
    """The running ``(value [M], row [M])`` of each column's smallest (``better=np.less``) or largest
    (``np.greater``) entry, the first row on ties, with the rows ``a ..`` of ``block [b, M]`` folded in."""
    at = block.argmin(0) if better is np.less else block.argmax(0)
    val = block[at, np.arange(block.shape[1])]
    if run is None:
        return val, at.astype(np.int64) + a
    take = better(val, run[0])  # strictly better: an earlier row keeps a tie
    return np.where(take, val, run[0]), np.where(take, at + a, run[1])
