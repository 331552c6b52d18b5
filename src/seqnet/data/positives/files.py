"""Readers of explicit positives files (:func:`read_positives`): JSON, CSV, ``.npy`` / pickles, ``GT.npz``."""

from __future__ import annotations

import dataclasses
import logging
import re
from pathlib import Path

import numpy as np

from ...core.errors import DatasetError
from ...core.log import logger
from ...security.arrays import is_npy, read_header, read_npy, read_npz
from ...security.inputs import open_input
from ...security.jsonfile import parse_json
from ...security.limits import INDEX_MAX
from ..readers import field_separator, read_text
from .csr import ONE_BASED, Positives

INTEGER = re.compile(r"-?[0-9]{1,19}")  # an index of a text file: ASCII digits ("²".isdigit() is True)


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
    rows = zero_one_rows(data)
    if rows is not None and (rows.dtype == bool or repeats(rows)):  # a 0/1 matrix: no list of indices repeats one
        return numeric_matrix(rows, p)
    found = Positives.from_lists([r if isinstance(r, list) else [r] for r in data], str(p))
    return found if rows is None else dataclasses.replace(found, zero_one_width=int(rows.shape[1]))


QUERY_COLUMNS = ("query", "queries", "q", "qry")  # a CSV header's names of the query column (lower case)
REFERENCE_COLUMNS = ("reference", "references", "ref", "refs", "r", "db", "database", "map", "gallery")
_SUFFIX = re.compile(r"[ _-]*(index|indices|idx|id|ids|frame|frames|image|images)$")


def csv_columns(fields: list[str], where: str) -> tuple[int, int]:
    """``(query column, reference column)`` named by the header ``fields`` of a positives CSV: ``query`` and
    ``reference`` in either order, any case, or an alias (:data:`QUERY_COLUMNS`, :data:`REFERENCE_COLUMNS`; a
    suffix such as ``_index`` or ``_id`` is ignored). A header naming anything else is refused: a guess could
    swap the columns, and swapped positives score R@1 near 0 without any error."""
    names = [_SUFFIX.sub("", f.strip().strip("\ufeff\"'").strip().lower()) for f in fields]
    kinds = ["query" if n in QUERY_COLUMNS else "reference" if n in REFERENCE_COLUMNS else None for n in names]
    if len(fields) != 2 or sorted(map(str, kinds)) != ["query", "reference"]:
        raise DatasetError(f"{where}: header {','.join(fields)[:80]!r} does not name a query and a reference column; "
                           "expected 'query,reference' or 'reference,query' (aliases: q, ref, db, database), or no "
                           "header (then the columns are query,reference)")
    return kinds.index("query"), kinds.index("reference")


def _read_csv(p: Path) -> Positives:
    """``query,reference`` pairs (``;`` also separates; a file whose first line has neither: tabs or spaces,
    :func:`seqnet.data.readers.field_separator`; reference -1: the query has no match), gathered into CSR
    at once (:meth:`Positives.from_pairs`). A first line that is no pair is a header naming the two columns, in
    either order (:func:`csv_columns`). The number of queries is bounded by the file: a query index beyond
    :func:`query_bound` of its pairs is refused."""
    queries, refs, (qc, rc), order = [], [], (0, 1), "query,reference"
    lines = read_text(p, "positives file").splitlines()  # (a byte-order mark dropped)
    sep = field_separator(next((line for line in lines if line.strip()), ""))
    split, between = ((lambda line: line.replace(";", ",").split(","), "',' or ';'") if sep in (",", ";") else
                      ((lambda line: line.split("\t")), "tabs") if sep == "\t" else (str.split, "spaces"))
    for n, line in enumerate(lines, start=1):
        fields = [f.strip() for f in split(line)]
        if not line.strip():
            continue
        if n == 1 and not INTEGER.fullmatch(fields[0]):
            if re.match(r"-?[0-9]", fields[0]):  # data, not a header: its separator is not one seqnet reads
                raise DatasetError(f"{p}, line 1: {line[:80]!r} is neither two integers separated by ',', ';', a tab "
                                   "or spaces, nor a header naming the query and reference columns")
            qc, rc = csv_columns(fields, f"{p}, line 1")
            order = "reference,query" if qc else order
            continue
        if len(fields) != 2 or not all(INTEGER.fullmatch(f) for f in fields):
            raise DatasetError(f"{p}, line {n}: expected '{order}' (two integers), got {line[:80]!r} (fields "
                               f"separated by {between}, as on the first line)")
        q, r = int(fields[qc]), int(fields[rc])
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
    return dataclasses.replace(Positives.from_pairs(rows[keep], cols[keep], nq), open_ended=True)


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
                return numeric_matrix(arr, p)
            return Positives.from_lists([np.asarray(r).ravel() for r in np.asarray(arr, dtype=object).ravel()],
                                        str(p))
    from ...security.unpickle import load_npy_objects  # its tables load only for a pickled positives file
    value = load_npy_objects(p, str(p))
    arr = _object_array(value, p)
    if arr.ndim == 2 and arr.shape[1] == 2 and all(_is_index(q) for q in arr[:, 0]):
        return _vpr_bench(arr, p)
    if arr.ndim == 2 and arr.dtype != object:
        return numeric_matrix(arr, p)
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
    out = numeric_matrix(hard.T, p)  # one row per query (said once: GTsoft is read the same way, quietly)
    if soft is None:
        return out
    if soft.shape != hard.shape:
        raise DatasetError(f"{p}: GTsoft has shape {soft.shape} but GThard {hard.shape} (both [N_db, N_q])")
    if not (soft.dtype == bool or np.isin(soft, (0, 1)).all()):
        raise DatasetError(f"{p}: GTsoft must be a 0/1 [N_db, N_q] matrix like GThard")
    both = numeric_matrix(soft.T.astype(bool) | hard.T.astype(bool), p, quiet=True)
    return dataclasses.replace(out, soft=both)


def _is_index(x: object) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, bool)


def _vpr_bench(arr: np.ndarray, p: Path) -> Positives:
    """VPR-Bench's ``ground_truth_new.npy``: one ``[query index, [reference indices]]`` row per query."""
    order = np.array([int(q) for q in arr[:, 0]])
    if sorted(order.tolist()) != list(range(len(order))):
        missing = sorted(set(range(len(order))) - set(order.tolist()))
        one_based = sorted(order.tolist()) == list(range(1, len(order) + 1))
        raise DatasetError(f"{p}: VPR-Bench ground truth must list every query 0..{len(order) - 1} once "
                           f"(first missing or repeated near query {missing[0] if missing else int(order[0])})"
                           f"{ONE_BASED if one_based else ''}")
    lists: list = [None] * len(order)
    for q, refs in zip(order, arr[:, 1], strict=True):
        lists[q] = np.atleast_1d(np.asarray(refs)).ravel()
    return Positives.from_lists(lists, str(p))


FILE_PAIRS_HINT = ("save it as a CSV with the header 'query,reference', or as a JSON list with one list of reference "
                   "indices per query")
PYTHON_PAIRS_HINT = ("Positives.from_lists(arr.tolist()) for two reference indices per query, Positives.from_pairs("
                     "arr[:, 0], arr[:, 1], n_queries) for (query, reference) pairs; both from seqnet")


def numeric_matrix(arr: np.ndarray, p: Path, quiet: bool = False, pairs_hint: str = FILE_PAIRS_HINT) -> Positives:
    """A 2-D numeric array: a dense ``[Nq, Nr]`` ground-truth matrix when bool or 0/1 (any dtype), else one
    row of reference indices per query padded with -1; anything else is refused. ``quiet``: no INFO line;
    ``pairs_hint``: how to say which reading a ``[N, 2]`` array that may be pairs has (a file's, or Python's)."""
    if arr.dtype == bool or (arr.size and np.isin(arr, (0, 1)).all()):
        rows, cols = np.nonzero(arr)
        logger.log(logging.DEBUG if quiet else logging.INFO, "%s: read as a dense [%d, %d] ground-truth matrix "
                   "(0/1 entries)", p, *arr.shape)
        found = Positives.from_pairs(rows.astype(np.int64), cols.astype(np.int64), arr.shape[0])
        return dataclasses.replace(found, n_refs=int(arr.shape[1]))
    if arr.dtype.kind in "iu" or (arr.dtype.kind == "f" and np.isfinite(arr).all() and (arr == arr.round()).all()):
        if arr.shape[1] == 2 and len(arr) > 1 and np.array_equal(arr[:, 0], np.arange(len(arr))):
            raise DatasetError(f"{p}: a [{len(arr)}, 2] integer array whose first column is 0..{len(arr) - 1} may be "
                               "(query, reference) pairs or two reference indices per query, and the two readings "
                               f"differ; hint: {pairs_hint}")
        return Positives.from_lists(list(arr), str(p))
    raise DatasetError(f"{p}: a [{arr.shape[0]}, {arr.shape[1]}] {arr.dtype} array is neither a 0/1 ground-truth "
                       "matrix nor integer reference indices per query (padded with -1)")


def as_positives(value: object, n_queries: int, n_refs: int, where: str = "positives") -> Positives:
    """Explicit positives given in Python, checked against ``n_queries`` x ``n_refs``: a :class:`Positives`, one
    list of reference indices per query (``-1`` / empty: no match, as a JSON file), or a ``[N_query,
    N_reference]`` 0/1 matrix (or rows of indices padded with -1, as a ``.npy``), as ``--positives`` reads them.
    Rows of equal length holding only bools or 0/1 are the matrix when no index list could hold them (bools, or a
    value repeated in a row); rows that fit both readings at the matrix's width (at most 2 references) are refused."""
    if isinstance(value, Positives):
        return value.check(n_queries, n_refs, where)
    if isinstance(value, np.ndarray) and value.ndim == 2 and value.dtype != object:
        return numeric_matrix(value, Path(where), pairs_hint=PYTHON_PAIRS_HINT).check(n_queries, n_refs, where)
    if isinstance(value, (list, tuple, np.ndarray)):
        rows = zero_one_rows(value)
        if rows is not None and (rows.dtype == bool or repeats(rows)):  # no list of indices repeats an index
            return numeric_matrix(rows, Path(where), quiet=True).check(n_queries, n_refs, where)
        if rows is not None and rows.shape[1] == n_refs:
            raise DatasetError(f"{where}: {len(rows)} rows of {n_refs} zeros and ones read as a [N_query, "
                               f"N_reference] matrix and as reference indices per query give different positives "
                               "(hint: np.asarray(rows, dtype=bool) for the matrix, Positives.from_lists(rows) for "
                               "indices)")
        return Positives.from_lists(list(value), where).check(n_queries, n_refs, where)
    raise DatasetError(f"{where} must be a Positives, one list of reference indices per query, or a [N_query, "
                       f"N_reference] bool matrix, got {type(value).__name__} (hint: Positives.from_lists(lists), or "
                       "read_positives(FILE) for a file; both from seqnet)")


def zero_one_rows(value: object) -> np.ndarray | None:
    """``value`` as a 2-D array ``[N_query, L]`` when it is rows of equal length holding only bools or 0/1 (the
    form of a ground-truth matrix's ``.tolist()`` or of a JSON matrix), else None."""
    rows = list(value)  # type: ignore[call-overload]
    if not rows or not all(isinstance(r, (list, tuple, np.ndarray)) for r in rows):
        return None
    try:
        arr = np.asarray(rows)
    except (ValueError, TypeError):  # rows of different lengths
        return None
    if arr.ndim != 2 or not arr.size or arr.dtype.kind not in "biuf":
        return None
    return arr if arr.dtype == bool or np.isin(arr, (0, 1)).all() else None


def repeats(rows: np.ndarray) -> bool:
    """Whether some row of a ``[N, L]`` array of 0/1 holds one value twice (so it is no list of indices)."""
    return rows.shape[1] > 2 or (rows.shape[1] == 2 and bool((rows[:, 0] == rows[:, 1]).any()))
