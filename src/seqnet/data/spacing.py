"""How a traverse's positions advance from frame to frame: the one check that rows are in route order
(:func:`out_of_order`, with its hint :func:`order_hint`), that query and reference are sampled alike
(:func:`step_rates`) and that positions are metres, not degrees (:func:`looks_like_degrees`). Cheap: at most a few
thousand steps are sampled, numpy only."""

from __future__ import annotations

import numpy as np

from ..core.tensors import spread

SAMPLES = 2000  # consecutive steps sampled per traverse
POOL = 20000  # positions searched for a sampled position's nearest neighbour
FAR_RADII = 3.0  # a step longer than this many radii ...
FAR_SPACING = 5.0  # ... and this many times the traverse's own spacing is a jump
MOSTLY = 0.5  # the share of jumps above which the rows are likely not in route order
LONG_STEPS = 3.0  # a step longer than this many usual steps (75th percentile) is long; ...
ACROSS = 0.25  # ... it passes over the route when another frame lies within this share of its length of its middle
MANY_CROSSING = (3, 0.05)  # at least this many such steps, above this share of the steps: the rows' order
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


def crossing_steps(positions: np.ndarray, bounds: np.ndarray | None, samples: int = SAMPLES,
                   pool: int = POOL) -> tuple[np.ndarray, int, float]:
    """``[K]`` the rows ``i`` (of at most ``samples`` evenly spaced steps ``i → i+1`` within one sequence) whose step
    is long (over :data:`LONG_STEPS` usual steps: the 75th percentile of :func:`steps`) and passes over the route's
    own frames (one of at most ``pool`` lies within :data:`ACROSS` of the step's length from its middle): an order
    that skips along the route and comes back. A correct drive that speeds up, or crosses a tunnel, leaves no frame
    between two consecutive ones. Also the number of steps looked at and the usual step."""
    pos, n = np.asarray(positions, dtype=np.float64), len(positions)
    i = spread(n - 1, samples) if n > 1 else np.zeros(0, np.int64)
    if bounds is not None and len(bounds) == n:
        i = i[np.asarray(bounds)[i, 1] > i + 1]
    dist = np.linalg.norm(pos[i + 1] - pos[i], axis=1)
    step = float(np.percentile(dist, 75)) if len(dist) else 0.0
    long = np.flatnonzero(dist > LONG_STEPS * step) if step > 0 else np.zeros(0, np.int64)
    near, crossing = pos[spread(n, pool)], np.zeros(len(long), bool)
    for a in range(0, len(long), 256):  # [256, pool] distances at a time
        k = long[a:a + 256]
        mid = (pos[i[k]] + pos[i[k] + 1]) / 2
        gap = np.sqrt(np.square(near[None] - mid[:, None]).sum(-1).min(axis=1))
        crossing[a:a + 256] = gap < ACROSS * dist[k]  # the step's own ends lie half its length away
    return i[long[crossing]], len(i), step


def many_crossing(found: np.ndarray, n: int) -> bool:
    """Whether ``found`` crossing steps of ``n`` (:func:`crossing_steps`) are :data:`MANY_CROSSING`: the rows' order,
    not a stray position or a road driven twice."""
    return len(found) >= MANY_CROSSING[0] and len(found) > MANY_CROSSING[1] * n


def order_hint(named: bool) -> str:
    """The one fix for rows out of route order: named frames (positions matched to them by name) by a list of the
    images or names that sort in route order, else by time or by pairing positions and images by name."""
    if named:
        return ("put the images in route order, with a list of the images in route order (VPR-methods-evaluation's "
                "<folder>_images_paths.txt beside an image folder) or names that sort in route order (zero-padded "
                "frame numbers or timestamps first)")
    return "sort the rows by time, or pair them by image name: --ref-names / --query-names"


def out_of_order(positions: np.ndarray, bounds: np.ndarray | None, radius: float, unit: str,
                 side: str, named: bool = False) -> str | None:
    """Why the ``side`` traverse's rows may not be in route order (the one detector of it): most consecutive steps
    (within a sequence) are longer than :data:`FAR_RADII` radii and :data:`FAR_SPACING` times the route's own
    spacing (:func:`spacing`: shuffled rows), or many long steps pass over the route's own frames
    (:func:`crossing_steps`: frames sorted by a name that is not the drive's order); None otherwise (or with fewer
    than 10 steps). ``named``: the frames have image names (positions were matched to them by name: the hint
    (:func:`order_hint`) is then about the images' order, not the pairing)."""
    s = steps(positions, bounds)
    if len(s) < 10:
        return None
    own = spacing(positions)
    far = float((s > max(FAR_RADII * radius, FAR_SPACING * own)).mean())
    paired = (": the frames follow their images' order (the folder's sorted names, a list file's lines or the "
              "descriptor file's rows) and positions were matched to them by name") if named else ""
    if far > MOSTLY:
        return (f"{far:.0%} of the {side}'s consecutive frames lie far apart (median step {np.median(s):g} {unit} "
                f"against a radius of {radius:g} and a spacing of {own:g} between neighbouring positions): its rows "
                f"may not be in route order, or not paired with the right descriptors{paired}; sequence methods "
                f"assume frames in route order (hint: {order_hint(named)})")
    found, n, step = crossing_steps(positions, bounds)
    if not many_crossing(found, n):
        return None
    i = int(found[0])
    return (f"{len(found)} of the {n} steps between consecutive {side} frames pass over other frames of the route "
            f"(longer than {LONG_STEPS:g} usual steps of {step:.3g} {unit}, with frames at their middle; the first "
            f"between frames {i} and {i + 1}): its rows are not in route order{paired}, so sequence windows hold "
            f"frames far apart along the route, or in an order taken from their positions (hint: {order_hint(named)})")


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
