"""The map's own frames given as the query of ``seqnet localize --map`` (``--query`` pointed at the reference
images, or at the map's descriptor file): every answer is trivially right, so a one-line note says so, as the
dataset builders say "the query images are the reference images".

Cheap and bounded: the first :data:`SAMPLE` query descriptors are kept as they stream by and compared, row for
row, with the map's reference rows of the same numbers (the raw descriptors of a dataset map; the frame
descriptors of an index map when they are the raw ones, L2-normalised: compared after normalising, within
:func:`tolerance` of their dtype). A query of other images never comes within it (two images of one place differ
far more than a float's rounding).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np

SAMPLE = 32  # query frames compared with the map's rows
MIN_FRAMES = 3  # fewer query frames: too few to say anything


def reference_rows(ref: Any) -> np.ndarray | None:
    """``[Nr, D]`` the map's reference descriptors as the query's are made (raw), or None when it holds none: a
    dataset map's traverse (:class:`seqnet.reference.traverse.TraverseReference`), an index map's frame
    descriptors when they have the raw descriptors' D (a map re-ranking with an S_1 model stores its outputs), or
    neither (a distance matrix)."""
    traverse = getattr(ref, "traverse", None)
    if traverse is not None:
        return traverse.descriptors
    frames = getattr(ref, "frames", None)
    if isinstance(frames, np.ndarray) and frames.ndim == 2 and frames.shape[1] == getattr(ref, "input_dim", -1):
        return frames
    return None


def tolerance(dtype: np.dtype) -> float:
    """The largest element difference of two unit rows that are one row rounded: float16 3e-3, else 1e-5."""
    return 3e-3 if np.dtype(dtype).itemsize <= 2 else 1e-5


class CopyWatch:
    """Keeps the first :data:`SAMPLE` query descriptors of a stream (:meth:`watch`) and says afterwards
    (:meth:`note`) whether they are the map's reference rows ``rows [Nr, D]`` (None: nothing to compare)."""

    def __init__(self, rows: np.ndarray | None) -> None:
        self.rows = rows
        self.sample: list[np.ndarray] = []

    def watch(self, frames: Iterator[tuple[np.ndarray, float]]) -> Iterator[tuple[np.ndarray, float]]:
        """``frames`` as they are, the first :data:`SAMPLE` descriptors kept (copied)."""
        for d, ms in frames:
            if self.rows is not None and len(self.sample) < SAMPLE:
                self.sample.append(np.array(d, copy=True))
            yield d, ms

    def note(self) -> str | None:
        """A line when every sampled query descriptor equals the map's reference row of its number (at least
        :data:`MIN_FRAMES` of them, and as many distinct rows: the black frames two drives start with are alike),
        else None."""
        n = len(self.sample)
        if self.rows is None or n < MIN_FRAMES or len(self.rows) < n:
            return None
        q = np.stack(self.sample).astype(np.float64)
        r = np.asarray(self.rows[:n], np.float64)
        if q.shape != r.shape or len(np.unique(r, axis=0)) < MIN_FRAMES:  # black or constant frames: any drive
            return None
        if not np.array_equal(q, r):
            qn, rn = (a / np.maximum(np.linalg.norm(a, axis=1, keepdims=True), 1e-30) for a in (q, r))
            if not (np.abs(qn - rn).max() <= tolerance(self.rows.dtype)):
                return None
        return (f"the query frames are the map's own reference frames (the first {n} described identical to the "
                f"map's rows 0..{n - 1}, row for row): every answer is trivially right; hint: give images or "
                "descriptors of another traverse of the route as --query")
