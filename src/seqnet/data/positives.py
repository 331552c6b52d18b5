"""Explicit ground truth: for every query frame, the reference frames that show the same place.

Public VPR benchmarks often give their ground truth as lists (query i matches references
``[10i-1, 10i, 10i+1]``; ``-1`` or an empty list = no match) instead of positions and a radius.
:class:`Positives` holds such lists as one CSR structure (``indptr [Nq+1]``, ``indices [nnz]``);
when a dataset has them, Recall@K, training mining and every method use them instead of the radius.

Readers (:func:`read_positives`): a JSON list of lists; a CSV of ``query,reference`` pairs (with
or without a header); a ``.npy`` of a NumPy object array of index arrays (as pickled by many
benchmarks), read by a restricted unpickler that can rebuild NumPy arrays and nothing else, so a
hostile file cannot run code.
"""

from __future__ import annotations

import dataclasses
import logging
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..core.errors import DatasetError
from ..core.log import logger
from ..security.arrays import is_npy, read_header, read_npy, read_npz
from ..security.inputs import open_input
from ..security.jsonfile import parse_json
from ..security.limits import INDEX_MAX
from .readers import read_text

INTEGER = re.compile(r"-?[0-9]{1,19}")  # an index of a text file: ASCII digits ("²".isdigit() is True)


@dataclasses.dataclass(frozen=True)
class Positives:
    """Per query, the sorted unique matching reference indices (CSR: ``indices[indptr[i]:indptr[i+1]]``)."""

    indptr: np.ndarray  # [Nq + 1] int64
    indices: np.ndarray  # [nnz] int64
    n_refs: int | None = None  # the columns of the dense matrix it was read from (checked against the traverse)
    # soft positives (VPR_Tutorial's GTsoft, a superset of these): never negatives in training, neither a true
    # nor a false positive in PR; Recall@K counts only the hard ones
    soft: Positives | None = None

    @classmethod
    def from_lists(cls, lists: Sequence[Sequence[int]], where: str = "positives") -> Positives:
        """From one list of reference indices per query (``-1`` entries mean no match and are dropped)."""
        rows = [_indices(row, f"{where}: query {i}") for i, row in enumerate(lists)]
        indptr = np.concatenate([[0], np.cumsum([len(r) for r in rows])]).astype(np.int64)
        indices = np.concatenate(rows).astype(np.int64) if rows else np.zeros(0, np.int64)
        return cls(indptr, indices)

    def __len__(self) -> int:
        return len(self.indptr) - 1

    def of(self, q: int) -> np.ndarray:
        """The reference indices of query ``q``."""
        return self.indices[self.indptr[q] : self.indptr[q + 1]]

    def counts(self) -> np.ndarray:
        """``[Nq]`` number of positives of every query."""
        return np.diff(self.indptr)

    def check(self, n_queries: int, n_refs: int, where: str = "positives") -> Positives:
        """Raise :class:`DatasetError` unless there is one row per query and every index is a reference."""
        if len(self) != n_queries:
            raise DatasetError(f"{where}: {len(self)} rows of positives for {n_queries} query images (one per query)")
        if self.n_refs is not None and self.n_refs != n_refs:
            raise DatasetError(f"{where}: a ground-truth matrix of {self.n_refs} columns for {n_refs} reference "
                               "images (one column per reference)")
        if self.indices.size and self.indices.max() >= n_refs:
            q = int(np.searchsorted(self.indptr, int(np.argmax(self.indices >= n_refs)), side="right") - 1)
            raise DatasetError(f"{where}: query {q} lists reference {int(self.indices.max())}, but the reference "
                               f"traverse has {n_refs} images (indices 0..{n_refs - 1})")
        if self.soft is not None:
            self.soft.check(n_queries, n_refs, f"{where} (soft positives)")
        return self

    @classmethod
    def from_pairs(cls, rows: np.ndarray, cols: np.ndarray, n_queries: int) -> Positives:
        """From ``(query, reference)`` pairs ``rows [P]``, ``cols [P]`` (non-negative, ``rows < n_queries``;
        duplicates dropped). Sorted pair by pair: no product of indices, so none can overflow."""
        rows, cols = np.asarray(rows, dtype=np.int64).ravel(), np.asarray(cols, dtype=np.int64).ravel()
        order = np.lexsort((cols, rows))
        r, c = rows[order], cols[order]
        new = np.ones(len(r), dtype=bool)
        new[1:] = (r[1:] != r[:-1]) | (c[1:] != c[:-1])
        r, c = r[new], c[new]
        return cls(np.concatenate([[0], np.cumsum(np.bincount(r, minlength=n_queries))]).astype(np.int64), c)

    def pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """``(query [nnz], reference [nnz])`` of every positive pair."""
        return np.repeat(np.arange(len(self)), self.counts()), self.indices

    def select(self, q_idx: np.ndarray, r_idx: np.ndarray) -> Positives:
        """Positives of the queries ``q_idx [M]`` among the references ``r_idx [R]``, renumbered 0..R-1."""
        q_idx, r_idx = np.asarray(q_idx, dtype=np.int64), np.asarray(r_idx, dtype=np.int64)
        lookup = np.full(max(int(self.indices.max(initial=-1)), int(r_idx.max(initial=-1))) + 1, -1, np.int64)
        lookup[r_idx] = np.arange(len(r_idx))
        counts = self.counts()[q_idx]
        flat = np.repeat(self.indptr[q_idx] - np.cumsum(counts) + counts, counts) + np.arange(int(counts.sum()))
        rows, cols = np.repeat(np.arange(len(q_idx)), counts), lookup[self.indices[flat]]
        keep = cols >= 0
        soft = self.soft.select(q_idx, r_idx) if self.soft is not None else None
        return dataclasses.replace(Positives.from_pairs(rows[keep], cols[keep], len(q_idx)), soft=soft)

    def mask(self, n_refs: int) -> np.ndarray:
        """Dense ``[Nq, n_refs]`` bool matrix (for small blocks of queries)."""
        out = np.zeros((len(self), n_refs), dtype=bool)
        out[self.pairs()] = True
        return out

    def hits(self, retrieved: np.ndarray) -> np.ndarray:
        """``[M, K]`` bool: whether ``retrieved[m, k]`` (a reference index, -1 = none) is a positive of query m."""
        retrieved = np.asarray(retrieved, dtype=np.int64)
        width = max(int(self.indices.max(initial=0)), int(retrieved.max(initial=0))) + 1
        rows, cols = self.pairs()
        wanted = np.arange(len(retrieved))[:, None] * width + retrieved
        return np.isin(wanted, rows * width + cols) & (retrieved >= 0)


def _indices(row: object, where: str) -> np.ndarray:
    """The sorted unique reference indices of one query's list (``-1`` = no match, dropped); a value that is no
    index (a fraction, a text, beyond ``INDEX_MAX``, below -1) is a :class:`DatasetError` naming it."""
    try:
        a = np.asarray(row).ravel()
    except (TypeError, ValueError, OverflowError) as e:
        raise DatasetError(f"{where}: reference indices must be integers, got {str(row)[:60]}") from e
    if a.size and (a.dtype.kind not in "iu" and not (a.dtype.kind == "f" and np.all(a == np.round(a)))):
        raise DatasetError(f"{where}: reference indices must be integers, got {str(row)[:60]}")
    if a.size and a.dtype.kind in "uf" and np.abs(a).max() > INDEX_MAX:
        raise DatasetError(f"{where}: reference index {a.flat[int(np.argmax(np.abs(a)))]:.0f} is too large to be the "
                           "index of a reference image")
    a = a.astype(np.int64)
    if a.size and a.min() < -1:
        raise DatasetError(f"{where}: reference index {int(a.min())} is negative (-1 = no match)")
    return np.unique(a[a >= 0])


def read_positives(path: str | Path) -> Positives:
    """Explicit positives from ``.json`` (list of lists), ``.csv`` (query,reference pairs) or ``.npy``."""
    p = Path(path)
    if not p.is_file():
        raise DatasetError(f"positives file not found: {p}")
    readers = {".json": _read_json, ".csv": _read_csv, ".txt": _read_csv, ".npy": _read_object_npy,
               ".pkl": _read_object_npy, ".pickle": _read_object_npy, ".npz": _read_tutorial_npz}
    reader = readers.get(p.suffix.lower())
    if reader is None:
        raise DatasetError(f"positives file {p} must be .json, .csv, .npy, .pkl or .npz (got "
                           f"{p.suffix or 'no extension'!r})")
    return reader(p)


def _read_json(p: Path) -> Positives:
    data = parse_json(read_text(p), str(p))
    if not isinstance(data, list) or not all(isinstance(r, (list, int)) for r in data):
        raise DatasetError(f"{p}: expected a JSON list with one list of reference indices per query, "
                           "e.g. [[0, 1], [2], []]")
    return Positives.from_lists([r if isinstance(r, list) else [r] for r in data], str(p))


def _read_csv(p: Path) -> Positives:
    """``query,reference`` pairs (``;`` also separates; a first line that is no pair is a header; reference -1:
    the query has no match), gathered into CSR at once (:meth:`Positives.from_pairs`). The number of queries
    is bounded by the file: a query index beyond :func:`query_bound` of its pairs is refused."""
    queries, refs = [], []
    for n, line in enumerate(read_text(p, "positives file").splitlines(), start=1):
        fields = [f.strip() for f in line.replace(";", ",").split(",")]
        if not line.strip() or (n == 1 and not INTEGER.fullmatch(fields[0])):
            continue  # blank line or header
        if len(fields) != 2 or not all(INTEGER.fullmatch(f) for f in fields):
            raise DatasetError(f"{p}, line {n}: expected 'query,reference' (two integers), got {line[:80]!r}")
        q, r = int(fields[0]), int(fields[1])
        for value, what, low in ((q, "query", 0), (r, "reference", -1)):
            if not low <= value <= INDEX_MAX:
                raise DatasetError(f"{p}, line {n}: {what} index {value} is {'negative' if value < 0 else 'too large'} "
                                   f"(indices are 0..{INDEX_MAX}; reference -1 = no match)")
        queries.append(q)
        refs.append(r)
    if not queries:
        raise DatasetError(f"{p}: no query,reference pairs")
    rows, cols = np.array(queries, dtype=np.int64), np.array(refs, dtype=np.int64)
    nq, bound = int(rows.max()) + 1, query_bound(len(rows))
    if nq > bound:
        raise DatasetError(f"{p}: query index {nq - 1} is beyond what {len(rows)} pairs can describe (at most "
                           f"{bound} queries: queries without a pair are implied, not listed); hint: check the "
                           "file's columns (query,reference)")
    keep = cols >= 0
    return Positives.from_pairs(rows[keep], cols[keep], nq)


def query_bound(pairs: int) -> int:
    """The most queries a ground-truth file of ``pairs`` pairs may imply (its largest query index + 1)."""
    return pairs * 16 + 10**6


def _read_object_npy(p: Path) -> Positives:
    """A ``.npy`` of numbers (a 0/1 matrix or index rows), of objects (VPR-Bench's ``ground_truth_new.npy``), or a
    plain pickle under any name (``.pkl``, ``.pickle``, or a ``.npy`` made with ``pickle.dump``), read without an
    unpickler (:mod:`seqnet.security.unpickle`: nothing is imported, nothing can crash)."""
    if is_npy(p):
        with open_input(p, "positives file") as f:
            _, _, dtype = read_header(f, str(p))
        if not dtype.hasobject:
            arr = read_npy(p, False, "positives file")
            if arr.ndim == 2:
                return _numeric_matrix(arr, p)
            return Positives.from_lists([np.asarray(r).ravel() for r in np.asarray(arr, dtype=object).ravel()],
                                        str(p))
    from ..security.unpickle import load_npy_objects  # its tables load only for a pickled positives file
    value = load_npy_objects(p, str(p))
    arr = _object_array(value, p)
    if arr.ndim == 2 and arr.shape[1] == 2 and all(_is_index(q) for q in arr[:, 0]):
        return _vpr_bench(arr, p)
    if arr.ndim == 2 and arr.dtype != object:
        return _numeric_matrix(arr, p)
    return Positives.from_lists([_row(r, p) for r in arr.ravel()], str(p))


def _object_array(value: object, p: Path) -> np.ndarray:
    """What a pickle held, as an array of one entry per query (a list of rows, or an array)."""
    if isinstance(value, np.ndarray):
        return value
    if isinstance(value, (list, tuple)):
        rows = [list(r) if isinstance(r, (range, tuple)) else r for r in value]
        arr = np.empty(len(rows), dtype=object)
        for i, r in enumerate(rows):
            arr[i] = r
        if all(isinstance(r, list) and len(r) == 2 and _is_index(r[0]) for r in rows) and rows:
            pairs = np.empty((len(rows), 2), dtype=object)
            for i, r in enumerate(rows):
                pairs[i, 0], pairs[i, 1] = r[0], r[1]
            return pairs
        return arr
    raise DatasetError(f"{p}: a pickle of ground truth must hold a list (one entry per query) or an array, got "
                       f"{type(value).__name__}")


def _row(r: object, p: Path) -> np.ndarray:
    """One query's reference indices (a list, a range, an array, a single index)."""
    if isinstance(r, range):
        r = list(r)
    try:
        return np.asarray(r if not isinstance(r, (set, frozenset)) else sorted(r)).ravel()
    except (TypeError, ValueError, OverflowError) as e:
        raise DatasetError(f"{p}: a query's positives must be reference indices, got {str(r)[:60]}") from e


def _read_tutorial_npz(p: Path) -> Positives:
    """VPR_Tutorial's ``GT.npz``: ``GThard`` ``[N_db, N_q]`` bool, the positives, and the optional ``GTsoft``
    (same shape), the soft positives (:attr:`Positives.soft`, stored as ``GThard | GTsoft``)."""
    z = read_npz(p, "ground-truth archive", keys=("GThard", "GTsoft"))
    if "GThard" not in z:
        raise DatasetError(f"{p}: an .npz of positives needs VPR_Tutorial's 'GThard' [N_db, N_q] array")
    hard, soft = z["GThard"], z.get("GTsoft")
    if hard.ndim != 2:
        raise DatasetError(f"{p}: GThard must be a [N_db, N_q] matrix, got shape {hard.shape}")
    out = _numeric_matrix(hard.T, p)  # one row per query (said once: GTsoft is read the same way, quietly)
    if soft is None:
        return out
    if soft.shape != hard.shape:
        raise DatasetError(f"{p}: GTsoft has shape {soft.shape} but GThard {hard.shape} (both [N_db, N_q])")
    if not (soft.dtype == bool or np.isin(soft, (0, 1)).all()):
        raise DatasetError(f"{p}: GTsoft must be a 0/1 [N_db, N_q] matrix like GThard")
    both = _numeric_matrix(soft.T.astype(bool) | hard.T.astype(bool), p, quiet=True)
    return dataclasses.replace(out, soft=both)


def _is_index(x: object) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, bool)


def _vpr_bench(arr: np.ndarray, p: Path) -> Positives:
    """VPR-Bench's ``ground_truth_new.npy``: one ``[query index, [reference indices]]`` row per query."""
    order = np.array([int(q) for q in arr[:, 0]])
    if sorted(order.tolist()) != list(range(len(order))):
        missing = sorted(set(range(len(order))) - set(order.tolist()))
        raise DatasetError(f"{p}: VPR-Bench ground truth must list every query 0..{len(order) - 1} once "
                           f"(first missing or repeated near query {missing[0] if missing else int(order[0])})")
    lists: list = [None] * len(order)
    for q, refs in zip(order, arr[:, 1], strict=True):
        lists[q] = np.atleast_1d(np.asarray(refs)).ravel()
    return Positives.from_lists(lists, str(p))


def _numeric_matrix(arr: np.ndarray, p: Path, quiet: bool = False) -> Positives:
    """A 2-D numeric array: a dense ``[Nq, Nr]`` ground-truth matrix when bool or 0/1 (any dtype), else one
    row of reference indices per query padded with -1; anything else is refused. ``quiet``: no INFO line."""
    if arr.dtype == bool or (arr.size and np.isin(arr, (0, 1)).all()):
        rows, cols = np.nonzero(arr)
        logger.log(logging.DEBUG if quiet else logging.INFO, "%s: read as a dense [%d, %d] ground-truth matrix "
                   "(0/1 entries)", p, *arr.shape)
        found = Positives.from_pairs(rows.astype(np.int64), cols.astype(np.int64), arr.shape[0])
        return dataclasses.replace(found, n_refs=int(arr.shape[1]))
    if arr.dtype.kind in "iu" or (arr.dtype.kind == "f" and np.isfinite(arr).all() and (arr == arr.round()).all()):
        return Positives.from_lists(list(arr), str(p))
    raise DatasetError(f"{p}: a [{arr.shape[0]}, {arr.shape[1]}] {arr.dtype} array is neither a 0/1 ground-truth "
                       "matrix nor integer reference indices per query (padded with -1)")
