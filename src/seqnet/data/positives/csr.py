"""The CSR structure of explicit positives (:class:`Positives`): per query, its matching reference indices."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from ...core.errors import DatasetError
from ...security.limits import INDEX_MAX

# a file counted from 1 (no query or reference 0, one past the last): said beside the refusal
ONE_BASED = " (hint: the file seems to count from 1, with no index 0; seqnet counts queries and references from 0: " \
    "subtract 1 from every index)"


@dataclasses.dataclass(frozen=True)
class Positives:
    """Per query, the sorted unique matching reference indices (CSR: ``indices[indptr[i]:indptr[i+1]]``)."""

    indptr: np.ndarray  # [Nq + 1] int64
    indices: np.ndarray  # [nnz] int64
    n_refs: int | None = None  # the columns of the dense matrix it was read from (checked against the traverse)
    # soft positives (VPR_Tutorial's GTsoft, a superset of these): never negatives in training, neither a true
    # nor a false positive in PR; Recall@K counts only the hard ones
    soft: Positives | None = None
    # read from pairs (a CSV): a query after the last one listed has no match, so the rows end where the file's
    # pairs end and :meth:`check` adds the missing rows, empty, up to the number of query images
    open_ended: bool = False
    # read as indices from rows of 0/1 this wide (a JSON file): a [N_query, N_reference] matrix of that many
    # references would be read otherwise, so :meth:`check` refuses it when the reference has that many images
    zero_one_width: int | None = None

    @classmethod
    def from_lists(cls, lists: Sequence[Sequence[int]], where: str = "positives") -> Positives:
        """From one list of reference indices per query (``-1`` entries mean no match and are dropped)."""
        rows = [_indices(row, f"{where}: query {i}") for i, row in enumerate(lists)]
        indptr = np.concatenate([[0], np.cumsum([len(r) for r in rows])]).astype(np.int64)
        indices = np.concatenate(rows).astype(np.int64) if rows else np.zeros(0, np.int64)
        return cls(indptr, indices)

    def __len__(self) -> int:
        return len(self.indptr) - 1

    def __repr__(self) -> str:
        soft = ", with soft positives" if self.soft is not None else ""
        return f"Positives({len(self)} queries, {len(self.indices)} query-reference pairs{soft})"

    def of(self, q: int) -> np.ndarray:
        """The reference indices of query ``q``."""
        return self.indices[self.indptr[q] : self.indptr[q + 1]]

    def counts(self) -> np.ndarray:
        """``[Nq]`` number of positives of every query."""
        return np.diff(self.indptr)

    def check(self, n_queries: int, n_refs: int, where: str = "positives") -> Positives:
        """``self`` when there is one row per query and every index is a reference, else :class:`DatasetError`;
        positives read from pairs (:attr:`open_ended`) get empty rows for the queries after their last pair."""
        if self.open_ended and len(self) < n_queries:
            tail = np.full(n_queries - len(self), self.indptr[-1], np.int64)
            return dataclasses.replace(self, indptr=np.concatenate([self.indptr, tail]), open_ended=False).check(
                n_queries, n_refs, where)
        if len(self) != n_queries:
            flipped = self.n_refs == n_queries and len(self) == n_refs  # a dense [N_ref, N_query] matrix
            hint = f" (transposed? the matrix is [{n_refs}, {n_queries}]; seqnet reads [N_query, N_reference])"
            one_based = len(self) == n_queries + 1 and self.counts()[0] == 0
            hint = hint if flipped else ONE_BASED if one_based else ""
            raise DatasetError(f"{where}: {len(self)} rows of positives for {n_queries} query images (one per "
                               f"query){hint}")
        if self.zero_one_width == n_refs:
            raise DatasetError(f"{where}: {len(self)} rows of {n_refs} zeros and ones read as a [N_query, "
                               "N_reference] matrix and as reference indices per query give different positives "
                               "(hint: write a matrix with true / false entries, or indices as a CSV of "
                               "query,reference pairs)")
        if self.n_refs is not None and self.n_refs != n_refs:
            raise DatasetError(f"{where}: a ground-truth matrix of {self.n_refs} columns for {n_refs} reference "
                               "images (one column per reference)")
        if self.indices.size and self.indices.max() >= n_refs:
            q = int(np.searchsorted(self.indptr, int(np.argmax(self.indices >= n_refs)), side="right") - 1)
            one_based = int(self.indices.max()) == n_refs and int(self.indices.min()) >= 1
            raise DatasetError(f"{where}: query {q} lists reference {int(self.indices.max())}, but the reference "
                               f"traverse has {n_refs} images (indices 0..{n_refs - 1}){ONE_BASED * one_based}")
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
    index (a fraction, a text, beyond ``INDEX_MAX``, below -1) is a :class:`DatasetError` naming it. A set (or a
    range) is its members, as the pickle reader takes them."""
    if isinstance(row, (set, frozenset, range)):
        try:
            row = sorted(row)
        except TypeError as e:  # members of kinds that do not compare: no indices
            raise DatasetError(f"{where}: reference indices must be integers, got {str(row)[:60]}") from e
    try:
        a = np.asarray(row).ravel()
    except (TypeError, ValueError, OverflowError) as e:
        raise DatasetError(f"{where}: reference indices must be integers, got {str(row)[:60]}") from e
    only_01 = a.size > 2 and (a.dtype.kind not in "iu" or a.max() <= 1) and np.isin(a, (0, 1)).all()  # max first:
    matrix_row = (a.dtype == bool or only_01) and a.size > 1  # most index rows skip the isin
    hint = (" (a row of a 0/1 [N_query, N_reference] matrix? hint: give a matrix as a numpy array, "
            "np.asarray(rows, dtype=bool), or as a .npy file)") if matrix_row else ""
    if a.size and (a.dtype.kind not in "iu" and not (a.dtype.kind == "f" and np.all(a == np.round(a)))):
        raise DatasetError(f"{where}: reference indices must be integers, got {str(row)[:60]}{hint}")
    if matrix_row:  # more than two entries of only 0 and 1: an index repeats, which no list of indices does
        raise DatasetError(f"{where}: reference indices repeat, got {str(row)[:60]}{hint}")
    if a.size and a.dtype.kind in "uf" and np.abs(a).max() > INDEX_MAX:
        raise DatasetError(f"{where}: reference index {a.flat[int(np.argmax(np.abs(a)))]:.0f} is too large to be the "
                           "index of a reference image")
    a = a.astype(np.int64)
    if a.size and a.min() < -1:
        raise DatasetError(f"{where}: reference index {int(a.min())} is negative (-1 = no match)")
    return np.unique(a[a >= 0])
