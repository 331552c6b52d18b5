"""Descriptor values that every search would accept and rank wrongly: rows that share a common offset far larger
than what tells them apart (:func:`narrow_directions`)."""

from __future__ import annotations

import numpy as np

from ...core.tensors import NARROW_SPREAD, direction_spread
from ..traverse import Dataset

OFFSET_HINT = ("hint: subtract a common mean from both sides before saving, e.g. m = ref.mean(axis=0); "
               "np.save(path, x - m) for the reference and the query (or describe the images again)")


def narrow_directions(ds: Dataset) -> str | None:
    """One line when the descriptor rows of ``ds`` (both sides) point nearly the same way once L2-normalised, as
    every search compares them (:func:`seqnet.core.tensors.direction_spread` below
    :data:`~seqnet.core.tensors.NARROW_SPREAD`: a common offset hundreds of times the rows' spread, e.g. features in
    raw units or de-quantised codes); float32 distances then lose the differences between places (R@1 0.99 -> 0.75
    at an offset 1000 times the spread, 0.00 at 10000). None otherwise."""
    both = [t.descriptors for t in (ds.reference, ds.query)]
    if any(x.ndim != 2 for x in both) or both[0].shape[1] != both[1].shape[1]:
        return None
    x = np.concatenate([x[np.linspace(0, len(x) - 1, min(len(x), 2048)).astype(np.int64)] for x in both])
    s = direction_spread(x)
    if not s < NARROW_SPREAD:
        return None
    return (f"the descriptors point nearly the same way once L2-normalised (their directions spread {s:.2g}, where "
            f"distinct places spread 0.3 or more): they share a common offset far larger than what tells places "
            f"apart, and float32 distances lose those differences, so R@K can fall to chance; {OFFSET_HINT}")
