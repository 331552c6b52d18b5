"""Two sides whose descriptors are not comparable: made by two different models, reduced by a PCA fitted on each
traverse separately, or preprocessed differently. Every search ranks such descriptors, and R@K comes out low but
above chance, without a word. :func:`separate_pcas` reads a PCA of each side's own in the values (exactly centred,
uncorrelated columns on both sides); :func:`foreign_spaces` reads any cause in the ground truth: each side follows
its route, but a query is no nearer to its own place than to others."""

from __future__ import annotations

import numpy as np

from ...core.tensors import spread
from ..traverse import Dataset, Traverse
from .revisits import nearer_share

FOREIGN_SHARE = 0.4  # the median query's share of other places nearer than its own, at least: near random
CLEAR = 3  # other places: beyond this many radii (or positives' counts) of the query's own
FOREIGN_MIN = 100  # queries with an own place and enough other places, at least, before the share says anything
#                   (one describer on 30-60 Nordland64 frames read up to 0.73 on 1 stretch in 36; none from 100)
OTHERS_MIN = 10  # other places' references per query, at least
ROUTE_MIN = 20  # rows followed by one of their sequence, at least, before route_share says anything
ROUTE_SHARE = 0.25  # each side's route_share, at most: its rows follow a route (unrelated rows, e.g. noise: 0.5)
SPACES_HINT = ("hint: describe both traverses with one describer in one run (seqnet dataset from-images REF QUERY "
               "...), fit one PCA on both sides and apply it to each (seqnet describe --dim, or seqnet train --pca), "
               "and preprocess both alike")


def foreign_spaces(ds: Dataset, samples: int = 200) -> str | None:
    """One line when the query's descriptors look made in another space than the reference's: for the median of
    ``samples`` evenly spaced queries with a correct reference (its middle explicit positive, or the nearest reference
    by position when within the radius), at least :data:`FOREIGN_SHARE` of ``samples`` evenly spaced references of
    other places are nearer to it (L2-normalised) than its own. A random ranking gives 0.5; one describer on both
    sides gave 0.00–0.01 on the whole Nordland64 route (summer/winter, pixels and NetVLAD) and 0.21–0.22 on a
    300-frame stretch of it (pixels with PCA 64 to 256: places alike), the query rotated into another basis 0.49–0.76,
    a PCA fitted per traverse 0.38–0.89. Said only when each side on its own follows its route (:func:`route_share` at
    most :data:`ROUTE_SHARE`; 0.02–0.12 on those datasets): each side is a route, but the two do not meet. None
    otherwise, or with too few such queries; the reference's positions given for the query too is
    :func:`.positions.copied_positions`'s line."""
    if ds.query.dim != ds.reference.dim or len(ds.reference) < OTHERS_MIN or len(ds.query) < FOREIGN_MIN:
        return None
    if ds.positives is None and ds.position_unit != "frames" and \
            np.array_equal(np.asarray(ds.query.positions), np.asarray(ds.reference.positions)):
        return None  # copied_positions's case (frame numbers are equal by design)
    share = own_place_share(ds, samples)
    if share is None or share < FOREIGN_SHARE:
        return None
    routes = [route_share(t, samples) for t in (ds.reference, ds.query)]
    if any(r is None or r > ROUTE_SHARE for r in routes):
        return None  # a side whose rows do not follow a route (noise, shuffled frames): not a matter of two spaces
    return (f"the query's descriptors do not look comparable with the reference's: for the median query, "
            f"{share:.0%} of other places' references are nearer to it than its own place's (a random ranking gives "
            "50%; one describer on both sides 0-22% on Nordland summer/winter), so the methods rank mostly noise: "
            "descriptors made by two different models, a PCA fitted on each traverse separately, or preprocessed "
            f"differently? (or a ground truth that pairs the wrong frames); {SPACES_HINT}")


def own_place_share(ds: Dataset, samples: int = 200) -> float | None:
    """The median, over up to ``samples`` evenly spaced queries with a correct reference, of the share of
    ``samples`` evenly spaced references of other places (clear of its neighbourhood: :func:`_other_places`) that
    are nearer to the query than its correct one; None with fewer than :data:`FOREIGN_MIN` such queries."""
    items = spread(len(ds.query), samples)
    own, keep = _own_places(ds, items)
    items, own = items[keep], own[keep]
    if len(items) < FOREIGN_MIN:
        return None
    j = spread(len(ds.reference), samples)
    return nearer_share(ds.query.descriptors[items], ds.reference.descriptors[own], ds.reference.descriptors[j],
                        _other_places(ds, items, j), OTHERS_MIN, FOREIGN_MIN)


def route_share(t: Traverse, samples: int = 200) -> float | None:
    """How much a traverse's descriptors follow its route: the median, over up to ``samples`` evenly spaced rows i
    followed by a row of the same sequence, of the share of ``samples`` evenly spaced rows more than :data:`CLEAR`
    rows away that are nearer to row i (L2-normalised) than row i + 1. Near 0 for images of a route (the next frame
    looks like this one), near 0.5 for unrelated rows (noise); None with fewer than :data:`ROUTE_MIN` such rows."""
    n = len(t)
    if n < 2:
        return None
    i = spread(n - 1, samples)
    if t.seq_bounds is not None:
        i = i[np.asarray(t.seq_bounds)[i, 1] > i + 1]  # row i + 1 in the same sequence
    j = spread(n, samples)
    far = np.abs(i[:, None] - j[None, :]) > CLEAR  # [S, S'] rows of other places
    return nearer_share(t.descriptors[i], t.descriptors[i + 1], t.descriptors[j], far, OTHERS_MIN, ROUTE_MIN)


def _own_places(ds: Dataset, items: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(reference [S], found [S] bool)``: each query item's correct reference (its middle positive, or the nearest
    reference by position, found when within the radius)."""
    if ds.positives is not None:  # the middle positive: positives listed as a place and its neighbours (p-1, p, p+1)
        if not len(ds.positives.indices):  # no pair at all: no query has a place to compare with
            return np.zeros(len(items), np.int64), np.zeros(len(items), bool)
        counts = ds.positives.counts()[items]
        at = np.minimum(ds.positives.indptr[items] + counts // 2, max(len(ds.positives.indices) - 1, 0))
        return np.where(counts > 0, ds.positives.indices[at], 0), counts > 0
    r_pos, q_pos = np.asarray(ds.reference.positions, np.float64), np.asarray(ds.query.positions, np.float64)
    dist = np.empty(len(items))
    near = np.empty(len(items), np.int64)
    for k, i in enumerate(items):  # one query at a time: [R] of memory
        d2 = np.square(r_pos - q_pos[i]).sum(axis=1)
        near[k] = int(d2.argmin())
        dist[k] = float(np.sqrt(d2[near[k]]))
    return near, dist <= ds.radius


def _other_places(ds: Dataset, items: np.ndarray, refs: np.ndarray) -> np.ndarray:
    """``[S, S']`` bool: reference ``refs[b]`` shows another place than query ``items[a]``, clear of its
    neighbourhood (consecutive frames look alike): more than :data:`CLEAR` radii from it, or more than
    :data:`CLEAR` times its number of positives from each of its positives (explicit positives)."""
    if ds.positives is not None:
        rows = []
        for i in items:
            pos = ds.positives.of(int(i))
            gap = np.abs(refs[:, None] - pos[None, :]).min(axis=1) if len(pos) else np.full(len(refs), np.inf)
            rows.append(gap > CLEAR * max(len(pos), 1))
        return np.array(rows).reshape(len(items), len(refs))
    q_pos = np.asarray(ds.query.positions, np.float64)[items]
    r_pos = np.asarray(ds.reference.positions, np.float64)[refs]
    return np.sqrt(np.square(q_pos[:, None, :] - r_pos[None, :, :]).sum(axis=2)) > CLEAR * ds.radius


OWN_PCA_COLUMNS = 32  # the leading columns looked at
OWN_PCA_TOL = 1e-3  # column means within this share of their spread, correlations within it: exact to float32


def separate_pcas(ds: Dataset) -> str | None:
    """One line when each side of ``ds`` looks reduced by a PCA of its own (:func:`own_pca`): the two sides then have
    different axes (each axis's sign and order are the fit's), and R@1 falls without a word (0.90 -> 0.09 on a
    300-frame route, hunt F4). A PCA fitted on one side, or on both together, and applied to each leaves at most
    one side exactly centred; None then, when the sides differ in D, or when both have the same spread on every
    axis (the query made of the reference's own rows, reordered: one PCA fitted on them)."""
    if ds.query.dim != ds.reference.dim or not (own_pca(ds.reference.descriptors) and own_pca(ds.query.descriptors)):
        return None
    k = min(ds.query.dim, OWN_PCA_COLUMNS)
    spreads = [np.asarray(t.descriptors[:, :k], np.float64).std(axis=0) for t in (ds.reference, ds.query)]
    if np.allclose(spreads[0], spreads[1], rtol=OWN_PCA_TOL, atol=0):
        return None  # the same spread on every axis: the query is the reference's rows (copied_queries says it)
    return ("each side's descriptors look reduced by a PCA of its own (the leading columns of each side exactly "
            "centred, uncorrelated and in decreasing variance): PCAs fitted on each traverse separately give the two "
            f"sides different axes (signs, order), so distances across them mean little; {SPACES_HINT}")


def own_pca(x: np.ndarray) -> bool:
    """Whether the rows ``x [N, D]`` look like the output of a PCA fitted on themselves: their leading (up to
    :data:`OWN_PCA_COLUMNS`) columns centred and uncorrelated to :data:`OWN_PCA_TOL` (of their spread), in
    decreasing variance, with at least two columns and more rows than columns looked at."""
    if x.ndim != 2 or min(x.shape[1], OWN_PCA_COLUMNS) < 2 or len(x) <= 2 * min(x.shape[1], OWN_PCA_COLUMNS):
        return False
    k = min(x.shape[1], OWN_PCA_COLUMNS)
    cols = np.asarray(x[:, :k], np.float64)
    mean, std = cols.mean(axis=0), cols.std(axis=0)
    if not np.all(std > 0) or np.any(np.abs(mean) > OWN_PCA_TOL * std):
        return False
    corr = np.corrcoef(cols, rowvar=False)
    off = np.abs(corr - np.eye(k)).max()
    return bool(off < OWN_PCA_TOL and np.all(np.diff(std) <= OWN_PCA_TOL * std[:-1]))
