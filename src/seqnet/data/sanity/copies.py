"""Rows that are copies: the query images given as the reference (:func:`copied_queries`), and exact duplicate rows
within one side (:func:`duplicated_rows`); rows compared by a hash of their bytes, in blocks (bounded memory)."""

from __future__ import annotations

import numpy as np

from ...core.memory import BLOCK_BYTES
from ...core.tensors import spread
from ..traverse import Dataset


def copied_queries(ds: Dataset) -> str | None:
    """A line when every query descriptor of ``ds`` is an exact copy of a reference descriptor (the reference
    images given as the query: every metric would be trivially perfect), else None."""
    ref, qry = ds.reference.descriptors, ds.query.descriptors
    if ref.shape[1:] != qry.shape[1:] or ref.dtype != qry.dtype or len(qry) == 0 or len(ref) == 0:
        return None
    if ref.shape == qry.shape and _same_rows(ref, qry):
        return ("the query images are the reference images (identical descriptors, row for row): every metric is "
                "trivially perfect; hint: give the query traverse's own folder")
    copy = _copy_of(ref, qry)
    if copy is not None and _at_own_place(ds, copy):
        return (f"every one of the {len(qry)} query descriptors is an exact copy of a reference descriptor (the "
                "same images): every metric is trivially perfect; hint: give the query traverse's own images")
    return None


def _at_own_place(ds: Dataset, copy: np.ndarray) -> bool:
    """Whether each query's copy ``copy [M]`` (a reference index) is a true match of it: a copy elsewhere on the
    route (a training set that uses each traverse both ways, its sequences far apart) answers nothing."""
    if ds.positives is not None:
        return bool(ds.positives.hits(copy[:, None]).all())
    q, r = np.asarray(ds.query.positions, dtype=np.float64), np.asarray(ds.reference.positions, dtype=np.float64)
    if q.shape[1:] != r.shape[1:]:
        return True  # no comparable positions: the copies alone are the evidence
    return bool((np.linalg.norm(q - r[copy], axis=1) <= ds.radius).all())


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


def _copy_of(ref: np.ndarray, qry: np.ndarray) -> np.ndarray | None:
    """``[M]``: for every row of ``qry [M, D]`` the index of an identical row of ``ref [N, D]``; None when a query
    row has none. A query row whose sum no reference row has is no copy (a pass at memory speed ends most calls);
    else candidates by a hash of the rows (:func:`_row_hashes`), each then compared whole."""
    if not np.isin(_row_sums(qry), _row_sums(ref)).all():
        return None
    r_hash, q_hash = _row_hashes(ref), _row_hashes(qry)
    order = np.argsort(r_hash, kind="stable")
    at = np.minimum(np.searchsorted(r_hash[order], q_hash), len(order) - 1)
    if not (r_hash[order][at] == q_hash).all():
        return None
    match, step = order[at], _block_rows(_row_bytes(qry))
    for i in range(0, len(qry), step):
        rows = np.sort(match[i:i + step])  # a memory map reads sorted rows faster
        got = np.asarray(ref[rows])[np.argsort(np.argsort(match[i:i + step], kind="stable"), kind="stable")]
        if not np.array_equal(got, qry[i:i + step]):
            return None
    return match


def _row_sums(a: np.ndarray) -> np.ndarray:
    """``[N]`` float64: the sum of every row (equal rows, equal sums: computed alike, block by block)."""
    step = _block_rows(int(np.prod(a.shape[1:])))
    return np.concatenate([np.asarray(a[i:i + step]).sum(axis=1, dtype=np.float64) for i in range(0, len(a), step)]
                          or [np.zeros(0)])


def _row_hashes(a: np.ndarray) -> np.ndarray:
    """``[N]`` uint64: a hash of every row's bytes (a fixed random linear form, wrapping), in blocks."""
    width = _row_bytes(a)
    word = np.uint32 if width % 4 == 0 else np.uint8  # 4-byte words: a quarter of the products
    words = width // np.dtype(word).itemsize
    weights = np.random.default_rng(0).integers(1, 2**63, size=words, dtype=np.uint64) | np.uint64(1)
    step, out = _block_rows(words), np.empty(len(a), np.uint64)
    for i in range(0, len(a), step):
        block = np.ascontiguousarray(a[i:i + step]).view(np.uint8).reshape(-1, width).view(word).astype(np.uint64)
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
