"""Checks of a traverse's arrays (:func:`validate_traverse`): shapes, dtypes, finite values, no all-zero row,
sequence bounds; each problem is one :class:`DatasetError` naming the traverse (and the image, when it has names)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..core.errors import DatasetError
from ..core.memmaps import read_rows
from ..core.memory import BLOCK_BYTES as MEMORY_BLOCK


def validate_traverse(t: Any) -> None:
    """Raise :class:`DatasetError` naming the first problem of traverse ``t`` (a ``seqnet.data.traverse.Traverse``)."""
    d, name = t.descriptors, label(t)
    if d.ndim != 2:
        raise DatasetError(f"{name}: descriptors must be [N, D], got shape {tuple(d.shape)}")
    if d.shape[0] == 0 or d.shape[1] == 0:
        raise DatasetError(f"{name}: descriptors are empty (shape {tuple(d.shape)})")
    if not np.issubdtype(d.dtype, np.floating):
        raise DatasetError(f"{name}: descriptors must be floating point, got dtype {d.dtype}")
    _check_finite(d, f"{name}: descriptors", nonzero=True, names=t.names)
    n, p = d.shape[0], t.positions
    if p.ndim != 2 or p.shape[1] not in (1, 2):
        flipped = (f"; they look transposed ([P, N] with N = {n} descriptors): pass positions.T ([{n}, {p.shape[0]}], "
                   "one row per image)" if p.ndim == 2 and p.shape[0] in (1, 2) and p.shape[1] == n else "")
        raise DatasetError(f"{name}: positions must be [N, 1] (frames) or [N, 2] (easting, northing), got shape "
                           f"{tuple(p.shape)}{flipped}")
    if p.shape[0] != n:
        flipped = (f"; the descriptors look transposed ([D, N] = {list(d.shape)}): pass descriptors.T ([N, D], one "
                   "row per image)" if d.shape[1] == p.shape[0] != n else "")
        raise DatasetError(f"{name}: {p.shape[0]} positions for {n} descriptors (must be equal){flipped}")
    _check_finite(p, f"{name}: positions")
    if t.names is not None and len(t.names) != n:
        raise DatasetError(f"{name}: {len(t.names)} image names for {n} descriptors")
    if t.seq_bounds is not None:
        _check_bounds(t.seq_bounds, n, name)


def label(t: Any) -> str:
    """The traverse's name in messages; one built without a name (``"traverse"``) says how to name it."""
    return t.name if t.name != "traverse" else "traverse (unnamed; Traverse(..., name='query' or 'reference') names it)"


def _check_bounds(b: np.ndarray, n: int, name: str) -> None:
    if b.shape != (n, 2):
        raise DatasetError(f"{name}: seq_bounds must be [{n}, 2], got shape {tuple(b.shape)}")
    idx = np.arange(n)
    bad = np.flatnonzero((b[:, 0] < 0) | (b[:, 0] > idx) | (b[:, 1] <= idx) | (b[:, 1] > n))
    if bad.size:
        i = int(bad[0])
        raise DatasetError(
            f"{name}: seq_bounds[{i}] = {b[i].tolist()} does not contain image {i} within 0:{n} "
            f"({bad.size} bad rows; each row is the half-open range [start, end) of the image's sequence)"
        )


def _check_finite(a: np.ndarray, what: str, chunk_bytes: int = MEMORY_BLOCK // 4, nonzero: bool = False,
                  names: list[str] | None = None) -> None:
    """NaN / inf anywhere (and, with ``nonzero``, an all-zero row) is a :class:`DatasetError` naming the first row
    (and its image, from ``names``).
    Read in blocks of ``chunk_bytes`` (a large memory map's pages are released after each: bounded memory)."""
    chunk = max(1, chunk_bytes // max(1, a[:1].nbytes))
    for s in range(0, a.shape[0], chunk):
        block = np.asarray(read_rows(a, s, s + chunk))
        if not np.isfinite(block).all():
            row = s + int(np.flatnonzero(~np.isfinite(block).all(axis=1))[0])
            image = f", image {names[row]}" if names is not None and row < len(names) else ""
            fix = ("a descriptor that failed; hint: describe that image again, or remove it" if nonzero else
                   "a position missing; hint: give it, or remove that image")
            raise DatasetError(f"{what} contain NaN or inf (first at row {row}{image}): {fix}")
        if nonzero and block.size:
            zero = ~block.any(axis=1)
            if zero.any():
                raise DatasetError(zero_rows_message(what, s + np.flatnonzero(zero), s, s + len(block) - 1, names))


def zero_rows_message(what: str, rows: np.ndarray, first: int, last: int, names: list[str] | None) -> str:
    """The one line for all-zero descriptor ``rows`` (of rows ``first..last``), naming their images when known."""
    row = int(rows[0])
    if names is None:
        return (f"{what}: row {row} is all zeros ({len(rows)} such rows in rows {first}..{last}); a zero descriptor "
                "matches nothing (e.g. a blank image: remove it)")
    shown = ", ".join(str(names[int(i)]) for i in rows[:3]) + (", ..." if len(rows) > 3 else "")
    return (f"{what}: row {row} (image {names[row]}) is all zeros ({len(rows)} such images in rows {first}..{last}: "
            f"{shown}); a zero descriptor matches nothing (e.g. a blank image: remove it; with frame-aligned folders "
            "remove the same name from both, which pairs them)")
