"""Positions that cannot be the query's own: the reference's positions given for the query too
(:func:`copied_positions`), which the images contradict."""

from __future__ import annotations

import numpy as np

from ...core.tensors import spread
from ..traverse import Dataset
from .revisits import nearer_share
from .truth import constant_positions

SAME_MIN = 10  # rows, at least, before equal positions say anything
SAME_AWAY = 0.25  # the own row's reference farther than this share of other places' (median query): not its place


def copied_positions(ds: Dataset, samples: int = 200) -> str | None:
    """Why the query's positions look like the reference's given twice: every query row's position equals the
    reference row's of the same index (two GPS drives never agree to the last digit) and the images disagree (the
    reference image of the query's own row is no nearer to it than those of other places: :func:`own_row_rank`);
    None otherwise: frame-aligned ground truth (frame numbers), explicit positives, or traverses recorded in sync
    that share one track (their own rows show their place)."""
    if ds.positives is not None or ds.position_unit == "frames":
        return None
    q, r = np.asarray(ds.query.positions), np.asarray(ds.reference.positions)
    if q.shape != r.shape or len(q) < SAME_MIN or not np.array_equal(q, r) or constant_positions(ds):
        return None
    away = own_row_rank(ds, samples)
    if away is None or away < SAME_AWAY:
        return None
    return (f"the query positions are the reference positions, row for row (all {len(q)} equal), but the images "
            f"disagree: the reference image of a query's own row is farther from it than {away:.0%} of other "
            "places' (median query): the same positions file given for both traverses? (hint: give the query "
            "traverse's own positions, e.g. --query-csv)")


def own_row_rank(ds: Dataset, samples: int = 200) -> float | None:
    """The median, over ``samples`` evenly spaced query rows i, of the share of ``samples`` evenly spaced reference
    rows j farther than the radius from row i's position whose descriptor is nearer to query i's (L2-normalised)
    than reference row i's: near 0 when row i of both traverses shows one place, near 0.5 when it does not; None
    with too few such rows."""
    n = min(len(ds.query), len(ds.reference))
    i, j = spread(n, samples), spread(len(ds.reference), samples)
    pos_i, pos_j = np.asarray(ds.query.positions[i], np.float64), np.asarray(ds.reference.positions[j], np.float64)
    far = np.linalg.norm(pos_i[:, None, :] - pos_j[None, :, :], axis=2) > ds.radius
    return nearer_share(ds.query.descriptors[i], ds.reference.descriptors[i], ds.reference.descriptors[j], far, 5, 5)
