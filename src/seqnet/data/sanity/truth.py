"""Ground truth that every command would score but that says little or the wrong thing: splits sharing queries,
positions all within the radius of each other."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..spacing import DEGREES_HINT, looks_like_degrees
from ..traverse import Dataset


def shared_queries(ds: Dataset, names: Sequence[str]) -> str | None:
    """Why the splits ``names`` (named splits, ranges or ``all``) misuse queries: pairs of them whose query
    ranges overlap (one line naming each pair); None when they are disjoint or cannot be read."""
    shared = []
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            ra, rb = ds.ranges(a), ds.ranges(b)
            if ra is None or rb is None:
                continue
            (s, e), (t, f) = ra["query"], rb["query"]
            if max(s, t) < min(e, f):
                shared.append(f"{a} (queries {s}:{e}) and {b} (queries {t}:{f}) share {min(e, f) - max(s, t)}")
    if not shared:
        return None
    return (f"splits {'; '.join(shared)} queries: what is chosen or trained on one is then scored on the same "
            "queries, so the val / test numbers are optimistic (hint: give disjoint query ranges)")


def constant_positions(ds: Dataset) -> str | None:
    """All positions within the radius of each other (the diagonal of their bounding box): every reference is
    a positive of every query (explicit positives decide instead, when there are some)."""
    if ds.positives is not None or not (len(ds.reference) and len(ds.query)):
        return None
    both = np.concatenate([ds.reference.positions, ds.query.positions])
    span = float(np.linalg.norm(both.max(axis=0) - both.min(axis=0)))
    if span > ds.radius:
        return None
    return (f"all {len(ds.reference)} reference and {len(ds.query)} query positions lie within {span:g} "
            f"{ds.position_unit} of each other, inside the radius {ds.radius:g}: every reference is within the "
            "radius of every query, so R@K is 1 trivially (hint: " + (
                DEGREES_HINT if looks_like_degrees(both) else "check the positions: constant GPS?") + ")")


