"""Ground truth that every command would score but that says little or the wrong thing: splits sharing queries,
positions all within the radius of each other."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...core.tensors import spread
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
            f"radius of every query, so R@K is 1 trivially (hint: {_spread_hint(ds, both)})")


KM_STEP = 0.1  # a median step per row below this (under the radius) reads as kilometres: 100 m per frame at most


def _spread_hint(ds: Dataset, both: np.ndarray) -> str:
    """What to do about positions ``both [N, P]`` (both traverses) all within the radius: degrees, a larger unit
    than the radius's (positions that advance row by row: kilometres, or frames with a radius in metres), or a
    frozen GPS (positions that do not move)."""
    if looks_like_degrees(both):
        return DEGREES_HINT
    steps = np.concatenate([np.linalg.norm(np.diff(np.asarray(t.positions, np.float64), axis=0), axis=1)
                            for t in (ds.reference, ds.query)])
    if not len(steps) or (steps > 0).mean() < 0.5:
        return "check the positions: constant GPS?"
    step = float(np.median(steps[steps > 0]))
    if ds.position_unit == "frames":
        return (f"the frame numbers advance {step:.2g} per row, and the radius {ds.radius:g} frames covers the whole "
                "route: a radius of 1-3 frames")
    if step >= KM_STEP:  # metre-sized steps: a short route inside a large radius, not another unit
        return (f"the positions advance {step:.2g} {ds.position_unit} per row (median), and the radius covers the "
                f"whole route: a radius near the frame spacing (e.g. --radius {max(step, 1.0):g})")
    return (f"the positions advance steadily, {step:.2g} per row (median), so the GPS is not constant: positions in "
            f"kilometres? multiply them by 1000, or give the radius in their unit (--radius {ds.radius / 1000:g})")


TRANSPOSED_SAMPLES = 200  # queries whose nearest reference tells the two readings of square positives apart
TRANSPOSED_BYTES = 512 << 20  # reference descriptors read at most for it
TRANSPOSED_SHARE, TRANSPOSED_RATIO = 0.2, 3.0  # the transposed reading's top-1 hits: at least, and times the given's


def transposed_positives(ds: Dataset) -> str | None:
    """Why explicit positives of a square dataset (as many queries as references) look transposed: the nearest
    reference of a sample of queries (by their descriptors) is a listed positive far more often when query and
    reference are swapped (a ``[N_reference, N_query]`` matrix, as VPR_Tutorial's ``GThard``, or pairs written
    ``reference,query``); None otherwise (symmetric positives read alike both ways)."""
    p, ref = ds.positives, ds.reference.descriptors
    n = len(ds.query)
    if p is None or len(ref) != n or n < 10 or ref.nbytes > TRANSPOSED_BYTES:
        return None
    q_idx = spread(n, TRANSPOSED_SAMPLES)
    top1 = nearest_rows(ref, np.asarray(ds.query.descriptors[q_idx], np.float32))
    rows, cols = p.pairs()
    listed = rows.astype(np.int64) * n + cols
    given = np.isin(q_idx * n + top1, listed).mean()
    swapped = np.isin(top1 * n + q_idx, listed).mean()
    if swapped < max(TRANSPOSED_SHARE, TRANSPOSED_RATIO * given):
        return None
    return (f"the positives read better transposed: the nearest reference of {len(q_idx)} sampled queries is a listed "
            f"positive for {given:.0%} of them, but for {swapped:.0%} with query and reference swapped (a "
            "[N_reference, N_query] matrix, as VPR_Tutorial's GThard, or pairs written reference,query?); hint: give "
            "the matrix transposed ([N_query, N_reference]) or the pairs as query,reference")


def nearest_rows(ref: np.ndarray, q: np.ndarray, block: int = 8192) -> np.ndarray:
    """``[M]`` int64: the row of ``ref [N, D]`` nearest (Euclidean) to each row of ``q [M, D]``, over blocks of
    ``block`` reference rows (first on ties)."""
    best = np.full(len(q), np.inf)
    arg = np.zeros(len(q), np.int64)
    for s in range(0, len(ref), block):
        r = np.asarray(ref[s:s + block], np.float32)
        d = (r * r).sum(axis=1)[None, :] - 2.0 * (q @ r.T)  # + |q|², the same for every reference
        j = d.argmin(axis=1)
        v = d[np.arange(len(q)), j]
        better = v < best
        best[better], arg[better] = v[better], j[better] + s
    return arg


WIDE_COUNT, WIDE_SHARE = 20, 0.1  # a frame radius giving the median query more correct references than both


def wide_frame_radius(ds: Dataset, samples: int = 200) -> str | None:
    """Why a radius in frames looks like one meant in metres: the median query has more than :data:`WIDE_COUNT`
    references within it and more than :data:`WIDE_SHARE` of the map (``--frame-aligned --radius 25``); None
    otherwise, with explicit positives, or when every reference is within it (:func:`constant_positions`)."""
    if ds.positives is not None or ds.position_unit != "frames" or len(ds.reference) < 4 or not len(ds.query):
        return None
    from scipy.spatial import cKDTree

    r_pos, q_pos = np.asarray(ds.reference.positions, np.float64), np.asarray(ds.query.positions, np.float64)
    counts = cKDTree(r_pos).query_ball_point(q_pos[spread(len(q_pos), samples)], ds.radius, return_length=True)
    m, n_r = float(np.median(counts)), len(r_pos)
    if m <= max(WIDE_COUNT, WIDE_SHARE * n_r) or m >= n_r:
        return None
    return (f"radius {ds.radius:g} frames: the median query has {m:.0f} correct references ({m / n_r:.0%} of the "
            f"{n_r}), so Recall@K is easy; with frame-numbered positions --radius counts frames, not metres (hint: "
            "a radius of 1-3 frames, or positions in metres)")


FROZEN_RUN = 10  # consecutive rows sharing one position, at least, before it looks like a frozen GPS fix
FROZEN_CHANGE = 0.5  # ... while their images change at least this share of the route's median change per row


def frozen_positions(positions: np.ndarray, desc: np.ndarray, side: str, pairs: int = 2000) -> str | None:
    """Why the positions ``[N, P]`` of a side look frozen (a GPS receiver repeating its last fix): a run of at least
    :data:`FROZEN_RUN` consecutive rows with one position while their descriptors ``desc [N, D]`` change as much as
    along the route (a stopped vehicle's images barely change: silent); None otherwise."""
    pos = np.asarray(positions, np.float64)
    if len(pos) <= FROZEN_RUN:
        return None
    same = np.r_[False, (np.diff(pos, axis=0) == 0).all(axis=1), False]
    edges = np.flatnonzero(np.diff(same.astype(np.int8)))
    starts, stops = edges[::2], edges[1::2] + 1  # run [start, stop): rows start..stop-1 share a position
    long = stops - starts >= FROZEN_RUN
    if not long.any():
        return None
    i = spread(len(pos) - 1, pairs)
    route = float(np.median(_steps(desc, i)))
    frozen = [(a, b) for a, b in zip(starts[long], stops[long], strict=True)
              if np.median(_steps(desc, np.arange(a, b - 1))) >= FROZEN_CHANGE * route > 0]
    if not frozen:
        return None
    a, b = max(frozen, key=lambda r: r[1] - r[0])
    more = f"; {len(frozen)} such runs, {sum(e - s for s, e in frozen)} rows in all" if len(frozen) > 1 else ""
    return (f"{b - a} consecutive {side} rows ({a}:{b}) share one position while their images change as much as "
            f"along the route{more}: a frozen GPS fix? (each takes that one place as its ground truth; hint: drop "
            "those rows or give them their true positions)")


def _steps(desc: np.ndarray, i: np.ndarray) -> np.ndarray:
    """``[K]`` the distance from descriptor row ``i`` to row ``i + 1`` for each of ``i [K]``."""
    a, b = np.asarray(desc[i], np.float64), np.asarray(desc[i + 1], np.float64)
    return np.linalg.norm(a - b, axis=1)


def degree_positions(ds: Dataset) -> str | None:
    """Why positions taken as metres look like degrees whatever the radius: both traverses within a unit of each
    other, |x| <= 180, |y| <= 90, fractional, away from the origin (:func:`seqnet.data.spacing.looks_like_degrees`;
    a tabletop's metres near 0 stay silent); None otherwise, or when every position is within the radius
    (:func:`constant_positions` says it)."""
    if ds.positives is not None or ds.position_unit != "metres" or not (len(ds.reference) and len(ds.query)):
        return None
    both = np.concatenate([ds.reference.positions, ds.query.positions]).astype(np.float64)
    if not looks_like_degrees(both) or np.abs(both).max() < 1.0 or constant_positions(ds):
        return None
    span = float(np.linalg.norm(np.ptp(both, axis=0)))
    x, y = np.median(both, axis=0)
    return (f"the positions span {span:.2g} units around ({x:.5f}, {y:.5f}), taken as metres with a radius of "
            f"{ds.radius:g}: {DEGREES_HINT}")


def unmatched_splits(ds: Dataset) -> str | None:
    """The splits none of whose queries has a true match within the split's reference range (``NAME=A:B,C:D`` is
    reference A:B, queries C:D: two query chunks given that way share no place), one line; a split against the whole
    reference is named for what it lacks instead (its queries' explicit positives are all empty, or no reference is
    within the radius); None when every split has some (or the dataset has no splits)."""
    bad, lines = [], []
    for name in ds.splits:
        sub = ds.split(name)
        if not len(sub.query) or _matched(sub):
            continue
        r, q = ds.splits[name]["reference"], ds.splits[name]["query"]
        if tuple(r) != (0, len(ds.reference)):
            bad.append(f"{name} (reference {r[0]}:{r[1]}, queries {q[0]}:{q[1]})")
        elif ds.positives is not None:  # against the whole reference: the range is not the cause
            lines.append(f"split {name} (queries {q[0]}:{q[1]}): the explicit positives list no reference for any "
                         "of its queries (an empty list is no match): it cannot be scored")
        else:
            lines.append(f"split {name} (queries {q[0]}:{q[1]}): no query has a reference within the radius "
                         f"{ds.radius:g}: it cannot be scored")
    if bad:
        lines.insert(0, f"split{'s' if len(bad) > 1 else ''} {'; '.join(bad)} {'have' if len(bad) > 1 else 'has'} no "
                        "query with a true match in the split's reference range: NAME=A:B,C:D is reference A:B and "
                        "queries C:D (hint: NAME=A:B alone selects queries A:B against the whole reference)")
    return "; ".join(lines) or None


def _matched(ds: Dataset) -> bool:
    """Whether some query of ``ds`` has a true match: an explicit positive, or a reference within the radius."""
    if ds.positives is not None:
        return bool((ds.positives.counts() > 0).any())
    if not len(ds.reference):
        return False
    from scipy.spatial import cKDTree

    d, _ = cKDTree(np.asarray(ds.reference.positions, np.float64)).query(
        np.asarray(ds.query.positions, np.float64), k=1)
    return bool((d <= ds.radius).any())


MATRIX_SHARE = 0.9  # reference rows peaking at their own column, at least, for [N, N] descriptors to be a matrix


def matrix_as_descriptors(ds: Dataset, samples: int = 200) -> str | None:
    """Why the descriptors look like a similarity or distance matrix: D equals the number of references and (of
    ``samples`` evenly spaced reference rows) at least :data:`MATRIX_SHARE` peak (max or min) at their own column,
    as a reference-to-reference matrix does; None otherwise (real descriptors with D = N peak there by chance)."""
    ref = ds.reference.descriptors
    n = len(ref)
    if ref.ndim != 2 or n < 10 or ref.shape[1] != n:
        return None
    i = spread(n, samples)
    rows = np.asarray(ref[i], np.float64)
    own = np.maximum((rows.argmax(axis=1) == i).mean(), (rows.argmin(axis=1) == i).mean())
    if own < MATRIX_SHARE:
        return None
    return (f"the reference descriptors are [{n}, {n}], D equal to the number of reference images, and {own:.0%} of "
            "the rows peak at their own column: a similarity or distance matrix? (hint: a [N_query, N_reference] "
            "matrix is scored with seqnet eval --distances FILE, with --similarity for similarities, not given as "
            "descriptors)")
