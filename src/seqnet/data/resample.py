"""Fixed-time re-sampling of a traverse: every N-th frame of the recorded order, whatever the distance.

The SeqNet paper's Oxford velocity test (its Fig. 3b, "Ox-FT") keeps every 6th frame of the test
traverses instead of one frame every 2 m: the split stays about the same size as the fixed-distance
one but the distance between consecutive frames follows the vehicle's speed. :func:`resample_dataset`
keeps frames ``0, N, 2N, ...`` of the query side, the reference side or both, and re-indexes every
per-frame field consistently: descriptors, positions, names, sequence bounds (a kept frame's bounds
are the kept frames of its sequence), the split ranges (the kept frames inside each range) and
explicit positives (the kept pairs, renumbered). Positions are kept as recorded, so radius ground
truth stays right by construction. What was done is recorded in ``extra["resample"]``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..core.errors import ConfigError, DatasetError
from ..core.log import ordinal
from ..core.memmaps import take_rows
from .traverse import Dataset, Traverse

RESAMPLE_SIDES = {"query": ("query",), "reference": ("reference",), "both": ("reference", "query")}


def kept_frames(n: int, every: int) -> np.ndarray:
    """``[ceil(n / every)]`` the frames ``0, every, 2·every, ...`` of a traverse of ``n`` frames."""
    if isinstance(every, bool) or not isinstance(every, (int, np.integer)) or every < 1:
        raise ConfigError(f"resample every must be an integer >= 1 (keep every N-th frame), got {every!r}")
    return np.arange(0, n, int(every), dtype=np.int64)


def resample_traverse(t: Traverse, keep: np.ndarray) -> Traverse:
    """The frames ``keep [M]`` of ``t``, in order: every N-th (increasing), or a variable-speed re-sampling
    (non-decreasing: a frame may repeat); each kept frame's sequence bounds become the kept frames of its
    sequence (``searchsorted`` on non-decreasing ``keep``)."""
    keep = np.asarray(keep, dtype=np.int64)
    if len(keep) > 1 and (np.diff(keep) < 0).any():
        raise ConfigError("resample: the kept frames must be in recorded order (non-decreasing)")
    bounds = None
    if t.seq_bounds is not None:
        b = t.seq_bounds[keep]  # [M, 2] half-open ranges in the old frame numbers
        bounds = np.stack([np.searchsorted(keep, b[:, 0]), np.searchsorted(keep, b[:, 1])], axis=1)
    names = None if t.names is None else [t.names[i] for i in keep]
    return dataclasses.replace(t, descriptors=take_rows(t.descriptors, keep), positions=t.positions[keep],
                               names=names, seq_bounds=bounds)


def resample_dataset(ds: Dataset, every: int | None, side: str = "query") -> Dataset:
    """``ds`` with every ``every``-th frame (of the recorded order) of ``side`` (``query``, ``reference`` or
    ``both``) kept; splits and explicit positives re-indexed (``every`` None or 1: ``ds`` itself).
    :class:`DatasetError` when a split would keep no frame of a side."""
    if every is None:
        return ds
    keep = kept_indices(ds, every, side)
    if every == 1:
        return ds
    splits = {}
    for split, rng in ds.splits.items():
        splits[split] = {s: _kept_range(keep[s], a, b, split, s, every) for s, (a, b) in rng.items()}
    positives = ds.positives.select(keep["query"], keep["reference"]) if ds.positives is not None else None
    done = [*ds.extra.get("resample", []), {"every": int(every), "side": side}]
    return dataclasses.replace(
        ds, reference=resample_traverse(ds.reference, keep["reference"]) if side != "query" else ds.reference,
        query=resample_traverse(ds.query, keep["query"]) if side != "reference" else ds.query,
        splits=splits, positives=positives, extra={**ds.extra, "resample": done})


def kept_indices(ds: Dataset, every: int, side: str) -> dict[str, np.ndarray]:
    """The frames each side of ``ds`` keeps (``{"reference": [R], "query": [Q]}``, old frame numbers)."""
    if side not in RESAMPLE_SIDES:
        raise ConfigError(f"resample side {side!r} is not one of {', '.join(RESAMPLE_SIDES)}")
    keep = {s: np.arange(len(getattr(ds, s)), dtype=np.int64) for s in ("reference", "query")}
    for s in RESAMPLE_SIDES[side]:
        keep[s] = kept_frames(len(getattr(ds, s)), every)
    return keep


def _kept_range(keep: np.ndarray, a: int, b: int, split: str, side: str, every: int) -> tuple[int, int]:
    """The new half-open range of the kept frames inside the old range ``a:b``."""
    lo, hi = int(np.searchsorted(keep, a)), int(np.searchsorted(keep, b))
    if lo >= hi:
        raise DatasetError(f"split {split!r}: no {side} frame of {a}:{b} is kept when keeping every {ordinal(every)} "
                           "frame (hint: a smaller --every, or a longer split)")
    return lo, hi
