"""``--ref-desc`` and ``--query-desc`` given the other way round: a side's count mismatch of descriptors and names
that the other side's descriptor file explains is said first (:func:`told_swapped`); the mismatch alone named a list
file to write, which does not help."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

from ...core.errors import DatasetError
from ..readers import read_descriptor_file


def swapped_sides(e: DatasetError, side: str, other_desc: str | Path | None) -> DatasetError:
    """``e`` (:func:`~seqnet.data.readers.read_descriptor_file`'s count mismatch of ``side``'s files) with a first
    hint when the other side's descriptor file ``other_desc`` has exactly as many rows as these names: ``--ref-desc``
    and ``--query-desc`` given the other way round (the error named a list file to write instead); else ``e``."""
    counts = getattr(e, "counts", None)
    if counts is None or other_desc is None:
        return e
    try:
        rows = read_descriptor_file(other_desc)[0].shape[0]
    except (DatasetError, OSError):
        return e
    if rows != counts[0] or rows == counts[1]:
        return e
    other = "query" if side == "reference" else "ref"
    return DatasetError(f"--ref-desc and --query-desc swapped? {other_desc} (--{other}-desc) has {rows} descriptors, "
                        f"one per {side} name here, and these names have {counts[1]} descriptors; {e}")



@contextlib.contextmanager
def told_swapped(side: str, other_desc: str | Path | None) -> Iterator[None]:
    """Building ``side``'s traverse: its count mismatch explained by the other side's descriptor file ``other_desc``
    (:func:`swapped_sides`) is raised with that said first."""
    try:
        yield
    except DatasetError as e:
        raise swapped_sides(e, side, other_desc) from e
