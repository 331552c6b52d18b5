"""How a traverse's positions advance from frame to frame: the checks that rows are in route order
(:func:`out_of_order`), that query and reference are sampled alike (:func:`step_rates`) and that positions are
metres, not degrees (:func:`looks_like_degrees`). Cheap: at most a few thousand steps are sampled, numpy only."""

from __future__ import annotations

import numpy as np

from ..core.tensors import spread

SAMPLES = 2000  # consecutive steps sampled per traverse
POOL = 20000  # positions searched for a sampled position's nearest neighbour
FAR_RADII = 3.0  # a step longer than this many radii ...
FAR_SPACING = 5.0  # ... and this many times the traverse's own spacing is a jump
MOSTLY = 0.5  # the share of jumps above which the rows are likely not in route order
RATE_RATIO = 1.5  # query and reference median steps further apart than this (either way) differ in rate


def steps(positions: np.ndarray, bounds: np.ndarray | None = None, samples: int = SAMPLES) -> np.ndarray:
    """Lengths of at most ``samples`` evenly spaced steps ``i → i+1`` of ``positions [N, P]`` within one
    sequence (``bounds [N, 2]``: the half-open sequence of each frame; None: one sequence)."""
    n = len(positions)
    if n < 2:
        return np.zeros(0)
    i = spread(n - 1, samples)
    if bounds is not None and len(bounds) == n:
        i = i[np.asarray(bounds)[i, 1] > i + 1]
    pos = np.asarray(positions, dtype=np.float64)
    return np.linalg.norm(pos[i + 1] - pos[i], axis=1)


def spacing(positions: np.ndarray, samples: int = 200, pool: int = POOL) -> float:
    """The median distance from ``samples`` evenly spaced positions to their nearest other position among at
    most ``pool`` evenly spaced ones (the route's own spacing, whatever the row order); 0 with < 2 positions."""
    pos = np.asarray(positions, dtype=np.float64)
    if len(pos) < 2:
        return 0.0
    near = spread(len(pos), pool)
    nearest = []
    for i in spread(len(pos), samples):
        d = np.square(pos[near] - pos[i]).sum(axis=1)
        d[near == i] = np.inf
        nearest.append(float(np.sqrt(d.min())))
    return float(np.median(nearest))


def out_of_order(positions: np.ndarray, bounds: np.ndarray | None, radius: float, unit: str,
                 side: str, named: bool = False) -> str | None:
    """Why the ``side`` traverse's rows may not be in route order: most consecutive steps (within a sequence)
    are longer than :data:`FAR_RADII` radii and :data:`FAR_SPACING` times the route's own spacing
    (:func:`spacing`); None otherwise (or with fewer than 10 steps). ``named``: the frames have image names
    (positions were matched to them by name: the hint is then about the images' order, not the pairing)."""
    s = steps(positions, bounds)
    if len(s) < 10:
        return None
    own = spacing(positions)
    far = float((s > max(FAR_RADII * radius, FAR_SPACING * own)).mean())
    if far <= MOSTLY:
        return None
    return (f"{far:.0%} of the {side}'s consecutive frames lie far apart (median step {np.median(s):g} {unit} "
            f"against a radius of {radius:g} and a spacing of {own:g} between neighbouring positions): its rows "
            "may not be in route order, or not paired with the right descriptors; sequence methods assume frames "
            "in route order " + (
                "(hint: the frames follow their images' order, the folder's natural sort, a list file's lines or the "
                "descriptor file's rows, and positions were matched to them by name: put the images in route order, "
                "with a list file or names that sort in route order)" if named else
                "(hint: sort the rows by time, or pair them by image name: --ref-names / --query-names)"))


def step_rates(query: np.ndarray, q_bounds: np.ndarray | None, reference: np.ndarray,
               r_bounds: np.ndarray | None, unit: str) -> str | None:
    """Why SeqMatch-style matchers may fail: the query's median step (:func:`steps`) differs from the
    reference's by more than :data:`RATE_RATIO` either way; None otherwise or when either is 0."""
    sq, sr = steps(query, q_bounds), steps(reference, r_bounds)
    if not (len(sq) and len(sr)):
        return None
    q, r = float(np.median(sq)), float(np.median(sr))
    if not (q > 0 and r > 0 and np.isfinite(q + r)) or max(q, r) / min(q, r) <= RATE_RATIO:
        return None
    dense = "query" if q < r else "reference"
    return (f"the query advances {q:g} {unit} per frame and the reference {r:g} {unit} (median steps, ratio "
            f"{q / r:.2g}): {unequal_steps(round(max(q, r) / min(q, r)), dense)}")


def unequal_steps(every: int, dense: str) -> str:
    """What unequal steps of the two traverses do, and the fix: re-sample the ``dense`` side every ``every``-th frame
    (or a velocity-robust matcher)."""
    return ("SeqMatch-style matchers assume both traverses advance by equal steps; use a velocity-robust matcher "
            "(raw+vseqmatch, s1+vseqmatch, raw+graph) or re-sample the denser side "
            f"(--resample-every {every} --resample-side {dense})")


def looks_like_degrees(positions: np.ndarray, samples: int = SAMPLES) -> bool:
    """Whether ``positions [N, 2]`` (easting, northing) look like longitude / latitude in degrees: they span
    less than one unit, |x| <= 180, |y| <= 90, and some have fractional parts (of ``samples`` evenly spaced)."""
    pos = np.asarray(positions, dtype=np.float64)
    if pos.ndim != 2 or pos.shape[1] != 2 or len(pos) == 0:
        return False
    p = pos[spread(len(pos), samples)]
    if not np.isfinite(p).all() or float(np.linalg.norm(np.ptp(p, axis=0))) >= 1.0:
        return False
    inside = bool((np.abs(p[:, 0]) <= 180).all() and (np.abs(p[:, 1]) <= 90).all())
    return inside and bool((p != np.round(p)).any())


DEGREES_HINT = ("positions look like degrees (latitude/longitude), not metres: convert them to UTM easting/northing "
                "metres (a positions CSV with lat,lon columns is converted by from-csv / from-images; "
                "seqnet.data.utm.latlon_to_utm; --positions-format robotcar-ins / kitti-oxts converts those logs) "
                "or give easting/northing")
