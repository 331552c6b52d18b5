"""Rows that are copies: query images that are reference images (:func:`copied_queries`), and exact duplicate rows
within one side (:func:`duplicated_rows`); rows compared by a hash of their bytes, in blocks (bounded memory)."""

from __future__ import annotations

import numpy as np

from ...core.memory import BLOCK_BYTES
from ...core.tensors import spread
from ..traverse import Dataset

COPIES_MIN = 3  # copies of the reference row of their own place, at least, before a partial count is said


def copied_queries(ds: Dataset) -> str | None:
    """A line when query descriptors of ``ds`` are exact copies of reference descriptors at their own place
    (reference images among the query's: those queries are found trivially): every one (the reference images given
    as the query: every metric trivially perfect), or at least :data:`COPIES_MIN` of them (a partial count, with
    their rows); else None. Copies of rows repeated within the reference (black frames of a tunnel) and copies far
    from the query's place (a training set that uses each traverse both ways) are not counted."""
    ref, qry = ds.reference.descriptors, ds.query.descriptors
    if ref.shape[1:] != qry.shape[1:] or ref.dtype != qry.dtype or len(qry) == 0 or len(ref) == 0:
        return None
    if ref.shape == qry.shape and _same_rows(ref, qry):
        return ("the query images are the reference images (identical descriptors, row for row): every metric is "
                "trivially perfect; hint: give the query traverse's own folder")
    copy = _copies(ref, qry)
    own = copy >= 0
    own[own] = _at_own_place(ds, np.flatnonzero(own), copy[own])
    if own.all():
        return (f"every one of the {len(qry)} query descriptors is an exact copy of a reference descriptor (the "
                "same images): every metric is trivially perfect; hint: give the query traverse's own images")
    if own.sum() < COPIES_MIN:
        return None
    rows = np.flatnonzero(own & ~np.isin(copy, _repeated(ref, copy[own])))
    if len(rows) < COPIES_MIN:
        return None
    of = f" of {ds.name} (its {describe_rows(rows)})" if "[" in ds.name else f" ({describe_rows(rows)})"  # a split
    return (f"{len(rows)} of the {len(qry)} query descriptors{of} are exact copies of the "
            "reference descriptors of their own place (reference images among the query's?): those queries are "
            "found trivially and R@K is optimistic; hint: check the query images, give the query traverse's own")


def describe_rows(rows: np.ndarray) -> str:
    """Rows ``rows [K]`` (sorted, unique) in a few words: ``rows 100:160``, ``rows 3:5, 9:12``, ``every 2nd row of
    0:300``, or the longest of many runs (``in 40 runs, the longest 100:160``)."""
    rows = np.asarray(rows, np.int64)
    cut = np.flatnonzero(np.diff(rows) != 1) + 1
    starts, stops = rows[np.r_[0, cut]], rows[np.r_[cut - 1, len(rows) - 1]] + 1
    if len(starts) <= 3:
        return "rows " + ", ".join(f"{a}:{b}" for a, b in zip(starts, stops, strict=True))
    step = np.diff(rows)
    if (step == step[0]).all():
        nth = {2: "2nd", 3: "3rd"}.get(int(step[0]), f"{step[0]}th")
        return f"every {nth} row of {rows[0]}:{rows[-1] + 1}"
    k = int(np.argmax(stops - starts))
    return f"in {len(starts)} runs from row {rows[0]} to {rows[-1]}, the longest {starts[k]}:{stops[k]}"


def _repeated(ref: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Those of the reference rows ``at [K]`` that another reference row repeats exactly (by a hash of the rows,
    :func:`_row_hashes`: a constant frame, as a tunnel's black ones, is no copied image)."""
    if not len(at):
        return at
    h = _row_hashes(ref)
    values, counts = np.unique(h, return_counts=True)
    return at[np.isin(h[at], values[counts > 1])]


def _at_own_place(ds: Dataset, q_idx: np.ndarray, copy: np.ndarray) -> np.ndarray:
    """``[K]`` bool: whether the copy ``copy [K]`` (a reference index) of each query ``q_idx [K]`` is a true match
    of it: a copy elsewhere on the route (a training set that uses each traverse both ways, its sequences far
    apart) answers nothing."""
    if ds.positives is not None:
        retrieved = np.full((len(ds.query), 1), -1, np.int64)
        retrieved[q_idx, 0] = copy
        return ds.positives.hits(retrieved)[q_idx, 0]
    q, r = np.asarray(ds.query.positions, dtype=np.float64), np.asarray(ds.reference.positions, dtype=np.float64)
    if q.shape[1:] != r.shape[1:]:
        return np.ones(len(q_idx), bool)  # no comparable positions: the copies alone are the evidence
    return np.linalg.norm(q[q_idx] - r[copy], axis=1) <= ds.radius


def _block_rows(row_bytes: int) -> int:
    """Rows of ``row_bytes`` bytes per block: a block's bytes widened to uint64 fill at most ``BLOCK_BYTES``."""
    return max(1, BLOCK_BYTES // max(1, row_bytes * 8))


def _row_bytes(a: np.ndarray) -> int:
    return a.itemsize * int(np.prod(a.shape[1:]))


def _same_rows(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether ``a [N, D]`` and ``b [N, D]`` are equal, compared in blocks (bounded memory; the first block that
    differs ends it)."""
    step = _block_rows(_row_bytes(a))
    return all(np.array_equal(a[i:i + step], b[i:i + step]) for i in range(0, len(a), step))


def _copies(ref: np.ndarray, qry: np.ndarray) -> np.ndarray:
    """``[M]`` int64: for every row of ``qry [M, D]`` the index of an identical row of ``ref [N, D]``, -1 where it
    has none. Only query rows whose sum some reference row has can be copies, and only reference rows whose sum
    some such query row has (a pass at memory speed ends most calls); their candidates by a hash of the rows
    (:func:`_row_hashes`), each then compared whole."""
    out = np.full(len(qry), -1, np.int64)
    q_sums, r_sums = _row_sums(qry), _row_sums(ref)
    q_at = np.flatnonzero(np.isin(q_sums, r_sums))
    if not len(q_at):
        return out
    r_at = np.flatnonzero(np.isin(r_sums, q_sums[q_at]))
    r_hash, q_hash = _row_hashes(ref, r_at), _row_hashes(qry, q_at)
    order = np.argsort(r_hash, kind="stable")
    at = np.minimum(np.searchsorted(r_hash[order], q_hash), len(order) - 1)
    found = r_hash[order][at] == q_hash
    q_at, match = q_at[found], r_at[order[at[found]]]
    step = _block_rows(_row_bytes(qry))
    for i in range(0, len(q_at), step):
        same = (np.asarray(ref[match[i:i + step]]) == np.asarray(qry[q_at[i:i + step]])).reshape(
            len(q_at[i:i + step]), -1).all(axis=1)
        out[q_at[i:i + step][same]] = match[i:i + step][same]
    return out


def _row_sums(a: np.ndarray) -> np.ndarray:
    """``[N]`` float64: the sum of every row (equal rows, equal sums: computed alike, block by block)."""
    step = _block_rows(int(np.prod(a.shape[1:])))
    return np.concatenate([np.asarray(a[i:i + step]).sum(axis=1, dtype=np.float64) for i in range(0, len(a), step)]
                          or [np.zeros(0)])


def _row_hashes(a: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
    """``[N]`` uint64: a hash of every row's bytes (a fixed random linear form, wrapping), in blocks; ``rows [K]``
    (sorted): of those rows only (``[K]``)."""
    width = _row_bytes(a)
    word = np.uint32 if width % 4 == 0 else np.uint8  # 4-byte words: a quarter of the products
    words = width // np.dtype(word).itemsize
    weights = np.random.default_rng(0).integers(1, 2**63, size=words, dtype=np.uint64) | np.uint64(1)
    n = len(a) if rows is None else len(rows)
    step, out = _block_rows(words), np.empty(n, np.uint64)
    for i in range(0, n, step):
        part = a[i:i + step] if rows is None else a[rows[i:i + step]]
        block = np.ascontiguousarray(part).view(np.uint8).reshape(-1, width).view(word).astype(np.uint64)
        out[i:i + step] = (block * weights).sum(axis=1)  # modulo 2**64
    return out


DUPLICATES_SHARE = 0.01  # exact duplicate rows above this share of a side (and at least 2) are named
DUPLICATES_BYTES = 64 << 20  # rows hashed at most (runs of consecutive rows spread over the side beyond it)
RUN = 256  # consecutive rows per run of the sample


def duplicated_rows(desc: np.ndarray, side: str) -> str | None:
    """Why ``desc [N, D]`` looks wrong: more than :data:`DUPLICATES_SHARE` of its rows (at least 2) are exact
    copies of another row (by a hash of every row, :func:`_row_hashes`; up to 100 candidates checked whole), among
    every row or, beyond :data:`DUPLICATES_BYTES`, runs of :data:`RUN` consecutive rows spread over ``desc``;
    None otherwise."""
    if desc.ndim != 2 or len(desc) < 2:
        return None
    k = max(2000, DUPLICATES_BYTES // max(1, _row_bytes(desc)))
    rows = np.arange(len(desc)) if len(desc) <= k else np.unique(
        spread(len(desc) - RUN + 1, max(1, k // RUN))[:, None] + np.arange(RUN))
    sub = np.asarray(desc[rows])
    h = _row_hashes(sub)
    _, first = np.unique(h, return_index=True)
    dup = np.setdiff1d(np.arange(len(h)), first)
    if len(dup) < max(2, DUPLICATES_SHARE * len(sub)):
        return None
    order = np.argsort(h, kind="stable")
    at = order[np.searchsorted(h[order], h[dup[:100]])]  # the first row of each checked duplicate's hash
    if not all(np.array_equal(sub[i], sub[j]) for i, j in zip(dup[:100], at, strict=True)):
        return None
    of = f"the {len(desc)}" if len(sub) == len(desc) else f"{len(sub)} checked (of {len(desc)})"
    return (f"{len(dup)} of {of} {side} rows are exact duplicates of another row (identical descriptors: the same "
            "image given twice, or a describer that failed on them?): duplicates carry no place and their ties are "
            "broken by index (hint: check the images and the describer)")
