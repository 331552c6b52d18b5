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
import io
import json
import pickle
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..core.errors import DatasetError
from ..core.utils import logger
from .readers import read_text


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
        rows = []
        for i, row in enumerate(lists):
            a = np.asarray(row).ravel()
            if a.size and (a.dtype.kind not in "iu" and not (a.dtype.kind == "f" and np.all(a == np.round(a)))):
                raise DatasetError(f"{where}: query {i}: reference indices must be integers, got {row!r}")
            a = a.astype(np.int64)
            if a.size and a.min() < -1:
                raise DatasetError(f"{where}: query {i}: reference index {int(a.min())} is negative (-1 = no match)")
            rows.append(np.unique(a[a >= 0]))
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
        """From ``(query, reference)`` pairs ``rows [P]``, ``cols [P]`` (duplicates dropped)."""
        key = np.unique(rows.astype(np.int64) * (int(cols.max(initial=0)) + 1) + cols)
        width = int(cols.max(initial=0)) + 1
        r, c = key // width, key % width
        return cls(np.concatenate([[0], np.cumsum(np.bincount(r, minlength=n_queries))]).astype(np.int64),
                   c.astype(np.int64))

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


def read_positives(path: str | Path) -> Positives:
    """Explicit positives from ``.json`` (list of lists), ``.csv`` (query,reference pairs) or ``.npy``."""
    p = Path(path)
    if not p.is_file():
        raise DatasetError(f"positives file not found: {p}")
    readers = {".json": _read_json, ".csv": _read_csv, ".txt": _read_csv, ".npy": _read_object_npy,
               ".npz": _read_tutorial_npz}
    reader = readers.get(p.suffix.lower())
    if reader is None:
        raise DatasetError(f"positives file {p} must be .json, .csv, .npy or .npz (got {p.suffix or 'no extension'!r})")
    return reader(p)


def _read_json(p: Path) -> Positives:
    try:
        data = json.loads(read_text(p))
    except json.JSONDecodeError as e:
        raise DatasetError(f"{p}: not valid JSON ({e})") from e
    if not isinstance(data, list) or not all(isinstance(r, (list, int)) for r in data):
        raise DatasetError(f"{p}: expected a JSON list with one list of reference indices per query, "
                           "e.g. [[0, 1], [2], []]")
    return Positives.from_lists([r if isinstance(r, list) else [r] for r in data], str(p))


def _read_csv(p: Path) -> Positives:
    pairs = []
    for n, line in enumerate(read_text(p).splitlines(), start=1):
        fields = [f.strip() for f in line.replace(";", ",").split(",")]
        if not line.strip() or (n == 1 and not fields[0].lstrip("-").isdigit()):
            continue  # blank line or header
        try:
            q, r = (int(f) for f in fields)
        except ValueError as err:
            raise DatasetError(f"{p}, line {n}: expected 'query,reference' (two integers), got {line!r}") from err
        if q < 0:
            raise DatasetError(f"{p}, line {n}: query index {q} is negative")
        pairs.append((q, r))
    if not pairs:
        raise DatasetError(f"{p}: no query,reference pairs")
    nq = max(q for q, _ in pairs) + 1
    lists: list[list[int]] = [[] for _ in range(nq)]
    for q, r in pairs:
        lists[q].append(r)
    return Positives.from_lists(lists, str(p))


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """Rebuilds NumPy arrays and scalars; any other global (code) is refused."""

    ALLOWED = {("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
               ("numpy", "ndarray"), ("numpy", "dtype"), ("numpy.core.multiarray", "scalar"),
               ("numpy._core.multiarray", "scalar")}

    def find_class(self, module: str, name: str):  # noqa: ANN201 - pickle's signature
        if (module, name) not in self.ALLOWED:
            raise DatasetError(f"refusing to load {module}.{name} from a pickle: only NumPy arrays are read")
        return super().find_class(module, name)


def _read_object_npy(p: Path) -> Positives:
    with open(p, "rb") as f:
        try:
            version = np.lib.format.read_magic(f)
            header = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
            if version not in header:
                raise ValueError(f".npy format version {version} is not supported here")
            shape, _, dtype = header[version](f, max_header_size=2**20)
        except ValueError as e:
            raise DatasetError(f"cannot read {p} as a .npy file ({e})") from e
        if dtype.kind != "O":
            f.seek(0)
            arr = np.load(f, allow_pickle=False)
        else:
            try:
                arr = _NumpyOnlyUnpickler(io.BytesIO(f.read())).load()
            except (pickle.UnpicklingError, EOFError, TypeError, ValueError) as e:
                raise DatasetError(f"cannot read {p}: not a pickled NumPy object array ({e})") from e
    if dtype.kind == "O":
        arr = np.asarray(arr, dtype=object).reshape(shape)
        if arr.ndim == 2 and arr.shape[1] == 2 and all(_is_index(q) for q in arr[:, 0]):
            return _vpr_bench(arr, p)
    elif arr.ndim == 2:
        return _numeric_matrix(arr, p)
    return Positives.from_lists([np.asarray(r).ravel() for r in np.asarray(arr, dtype=object).ravel()], str(p))


def _read_tutorial_npz(p: Path) -> Positives:
    """VPR_Tutorial's ``GT.npz``: ``GThard`` ``[N_db, N_q]`` bool, the positives, and the optional ``GTsoft``
    (same shape), the soft positives (:attr:`Positives.soft`, stored as ``GThard | GTsoft``)."""
    try:
        with np.load(p, allow_pickle=False) as z:
            if "GThard" not in z.files:
                raise DatasetError(f"{p}: an .npz of positives needs VPR_Tutorial's 'GThard' [N_db, N_q] array, "
                                   f"found {sorted(z.files)}")
            hard = np.asarray(z["GThard"])
            soft = np.asarray(z["GTsoft"]) if "GTsoft" in z.files else None
    except (OSError, ValueError) as e:
        raise DatasetError(f"cannot read {p} as an .npz file ({e})") from e
    if hard.ndim != 2:
        raise DatasetError(f"{p}: GThard must be a [N_db, N_q] matrix, got shape {hard.shape}")
    out = _numeric_matrix(hard.T, p)  # one row per query
    if soft is None:
        return out
    if soft.shape != hard.shape:
        raise DatasetError(f"{p}: GTsoft has shape {soft.shape} but GThard {hard.shape} (both [N_db, N_q])")
    if not (soft.dtype == bool or np.isin(soft, (0, 1)).all()):
        raise DatasetError(f"{p}: GTsoft must be a 0/1 [N_db, N_q] matrix like GThard")
    both = _numeric_matrix(soft.T.astype(bool) | hard.T.astype(bool), p)
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


def _numeric_matrix(arr: np.ndarray, p: Path) -> Positives:
    """A 2-D numeric array: a dense ``[Nq, Nr]`` ground-truth matrix when bool or 0/1 (any dtype), else one
    row of reference indices per query padded with -1; anything else is refused."""
    if arr.dtype == bool or (arr.size and np.isin(arr, (0, 1)).all()):
        rows, cols = np.nonzero(arr)
        logger.info("%s: read as a dense [%d, %d] ground-truth matrix (0/1 entries)", p, *arr.shape)
        found = Positives.from_pairs(rows.astype(np.int64), cols.astype(np.int64), arr.shape[0])
        return dataclasses.replace(found, n_refs=int(arr.shape[1]))
    if arr.dtype.kind in "iu" or (arr.dtype.kind == "f" and np.isfinite(arr).all() and (arr == arr.round()).all()):
        return Positives.from_lists(list(arr), str(p))
    raise DatasetError(f"{p}: a [{arr.shape[0]}, {arr.shape[1]}] {arr.dtype} array is neither a 0/1 ground-truth "
                       "matrix nor integer reference indices per query (padded with -1)")
