"""Where a traverse's positions say that sequence matching (or the radius) will not work as the user expects, one
warning line each (:func:`route_checks`, said when a dataset is built, by ``seqnet dataset check`` and per evaluated
split by ``seqnet eval``):

* :func:`standstill`: the vehicle stood still (consecutive rows that move less than one usual step in
  :data:`STILL_WINDOW` frames: GPS jitter around one place), a large share of a traverse or split;
* :func:`position_jumps`: positions jump many usual steps between consecutive frames of one sequence (a tunnel, a
  logger outage), so sequence windows straddle the jump (for a side in route order: rows out of it are
  :func:`seqnet.data.spacing.out_of_order`'s);
* :func:`sparse_reference`: a radius below the reference's frame spacing (each query has at most one correct
  reference, one between two frames none);
* :func:`radius_at_spacing`: a radius at a whole multiple of that spacing while the positions are so regular that
  many queries have a reference at the radius itself: whether it is a positive is decided by the positions'
  rounding.

Steps come from :mod:`seqnet.data.spacing`; every check is vectorised numpy, O(N) in the rows."""

from __future__ import annotations

import math

import numpy as np

from ..spacing import out_of_order, spacing, steps
from ..traverse import Dataset, Traverse
from .truth import frozen_positions

STILL_WINDOW = 10  # frames over which a standstill moves less than ...
STILL_STEPS = 1.0  # ... this many usual steps (under a tenth of the usual speed; GPS jitter of a few metres stays in)
STILL_SHARE = 0.1  # standing rows above this share of a traverse or of a split's rows are warned (R@K moves by it)
JUMP_STEPS = 10.0  # a step of more than this many usual steps inside one sequence is a jump
SPARSE = 0.9  # a radius below this share of the reference's spacing is warned (GPS noise moves the spacing a little)
AT_MULTIPLE = 0.02  # a radius within this share of the spacing from 1 or 2 times the reference's spacing ...
EDGE = 0.01  # ... with a reference within this share of the spacing from the radius (either side) ...
EDGE_SHARE = 0.5  # ... for at least this share of the queries is warned (1 m GPS noise on 10 m steps: 8-15%;
#                   frames exactly 10 m apart, stored to the millimetre: 100%)


def every_step(positions: np.ndarray, bounds: np.ndarray | None, lag: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """``[N - lag]`` the distance from row ``i`` to row ``i + lag`` of ``positions [N, P]``, and ``[N - lag]`` bool
    whether both rows lie in one sequence (``bounds [N, 2]``: the half-open sequence of each row; None: one)."""
    pos = np.asarray(positions, dtype=np.float64)
    if len(pos) <= lag:
        return np.zeros(0), np.zeros(0, bool)
    dist = np.linalg.norm(pos[lag:] - pos[:-lag], axis=1)
    inside = np.ones(len(dist), bool) if bounds is None or len(bounds) != len(pos) else \
        np.asarray(bounds)[:-lag, 1] > np.arange(len(dist)) + lag
    return dist, inside


def runs(mask: np.ndarray) -> np.ndarray:
    """``[K, 2]`` the half-open ranges of the runs of True in ``mask [N]``."""
    edges = np.flatnonzero(np.diff(np.r_[0, np.asarray(mask, np.int8), 0]))
    return edges.reshape(-1, 2)


def covered(ranges: np.ndarray, n: int) -> np.ndarray:
    """``[n]`` bool: whether each row lies in one of the half-open ``ranges [K, 2]``."""
    cover = np.zeros(n + 1, np.int64)
    np.add.at(cover, ranges[:, 0], 1)
    np.add.at(cover, ranges[:, 1], -1)
    return np.cumsum(cover[:n]) > 0


def usual_step(positions: np.ndarray, bounds: np.ndarray | None) -> float:
    """The usual step of ``positions`` within a sequence while moving: the 75th percentile of
    :func:`seqnet.data.spacing.steps` (a standstill of up to half the rows leaves it near the moving median); 0
    without any step."""
    s = steps(positions, bounds)
    return float(np.percentile(s, 75)) if len(s) else 0.0


def standstills(positions: np.ndarray, bounds: np.ndarray | None, step: float) -> np.ndarray:
    """``[K, 2]`` the runs of rows (half-open) in which the position moves less than :data:`STILL_STEPS` ``step``
    over :data:`STILL_WINDOW` frames of one sequence: a vehicle standing still, its GPS jittering."""
    n = len(positions)
    dist, inside = every_step(positions, bounds, STILL_WINDOW)
    if not len(dist) or step <= 0:
        return np.zeros((0, 2), np.int64)
    first = np.flatnonzero(inside & (dist < STILL_STEPS * step))  # rows first..first+WINDOW stand still
    return runs(covered(np.stack([first, first + STILL_WINDOW + 1], axis=1), n))


def standstill(t: Traverse, unit: str, side: str, parts: dict[str, tuple[int, int]],
               thin: str = "thin the frames by distance travelled", view: str = "") -> str | None:
    """Why the ``side`` traverse ``t`` holds a standstill (:func:`standstills`) worth a warning: its standing rows are
    at least :data:`STILL_SHARE` of the traverse or of one of ``parts`` (label: row range, e.g. each split's queries),
    so the one place they show weighs that much in Recall@K; None otherwise. ``thin``: the hint's other way
    (:func:`thin_hint`); ``view``: the name of the evaluated split (``d[test]``) whose rows are numbered from its
    first, said with them."""
    still = standstills(t.positions, t.seq_bounds, usual_step(t.positions, t.seq_bounds))
    n = len(t.positions)
    if not len(still) or not n:
        return None
    rows = covered(still, n)
    shares = {label: float(rows[a:b].mean()) for label, (a, b) in parts.items() if b > a and rows[a:b].any()}
    if max([rows.mean(), *shares.values()]) < STILL_SHARE:
        return None
    a, b = max(still, key=lambda r: r[1] - r[0])
    dist, inside = every_step(t.positions, t.seq_bounds)
    moving = inside & ~rows[:-1] & ~rows[1:]  # steps outside the standstills: the speed elsewhere
    step = float(np.median(dist[moving])) if moving.any() else usual_step(t.positions, t.seq_bounds)
    box = float(np.linalg.norm(np.ptp(np.asarray(t.positions[a:b], np.float64), axis=0)))
    more = f"; {len(still)} such runs, {int(rows.sum())} rows in all" if len(still) > 1 else ""
    whole = f"{rows.mean():.0%} of {view}'s {side} rows" if view else f"{rows.mean():.0%} of the {side}'s rows"
    of = ", ".join(f"{v:.0%} of {label}" for label, v in shares.items()) or whole
    return (f"{b - a} consecutive {side} rows ({a}:{b}{' of ' + view if view else ''}) lie within {box:.2g} {unit} "
            f"of each other while the {side} advances {step:.3g} {unit} per frame elsewhere (median step): the "
            f"vehicle stood still{more}; they are {of}, so the one place they show weighs that much in Recall@K, and "
            f"they break the constant-speed assumption of SeqMatch-style matchers (hint: drop those rows but one, or "
            f"{thin})")


def thin_hint(ds: Dataset) -> str:
    """How to thin ``ds``'s frames by distance: ``from-video --every-metres`` for a dataset from videos sampled by
    time (one sampled by distance already: drop the rows), else in general words."""
    sampling = ds.extra.get("sampling")
    if not isinstance(sampling, dict):
        return "thin the frames by distance travelled"
    if sampling.get("every_metres") is not None:
        return "raise from-video --every-metres above the GPS jitter"
    return "sample the videos by distance travelled: from-video --every-metres M"



def jumps(positions: np.ndarray, bounds: np.ndarray | None, step: float) -> np.ndarray:
    """``[J]`` the rows ``i`` whose step to ``i + 1`` inside one sequence is longer than :data:`JUMP_STEPS` ``step``
    and stays so across the neighbouring rows (``i - 1 → i + 1`` and ``i → i + 2``): a gap in the route, not a
    single stray position (which jumps away and back)."""
    far = JUMP_STEPS * step
    dist, inside = every_step(positions, bounds)
    if step <= 0 or not len(dist):
        return np.zeros(0, np.int64)
    big = np.flatnonzero(inside & (dist > far))
    two, _ = every_step(positions, None, 2)  # two[i]: row i to row i + 2
    before = np.r_[np.inf, two][big]  # row i - 1 to i + 1 (none before the first row)
    after = np.r_[two, np.inf][big]  # row i to i + 2 (none after the last)
    return big[(before > far) & (after > far)]


def position_jumps(t: Traverse, unit: str, side: str, view: str = "") -> str | None:
    """Why sequence windows of the ``side`` traverse ``t`` may straddle a gap: its positions :func:`jump
    <jumps>` inside one sequence (the largest named, with its size in usual steps); None otherwise, or when so many
    jump that the rows look out of route order (:func:`seqnet.data.spacing.out_of_order` says it, and
    :func:`route_checks` asks this only of a side in route order). ``view``: the evaluated split the frames are
    numbered in (as :func:`standstill`)."""
    step = usual_step(t.positions, t.seq_bounds)
    at = jumps(t.positions, t.seq_bounds, step)
    if not len(at) or len(at) > 0.1 * len(t.positions):
        return None
    dist, _ = every_step(t.positions, None)
    i = int(at[np.argmax(dist[at])])
    more = f" and {len(at) - 1} more jump(s) of over {JUMP_STEPS:g} usual steps" if len(at) > 1 else ""
    return (f"the {side}'s positions jump {dist[i]:.4g} {unit} ({dist[i] / step:.0f}× its usual step of {step:.3g} "
            f"{unit}) between frames {i} and {i + 1}{' of ' + view if view else ''} inside one sequence{more}: a "
            "tunnel, a logger outage or dropped frames? sequence windows that straddle a jump compare frames far apart "
            f"along the route, so the queries beside it are lost (hint: split the sequence there, e.g. a sequence "
            f"column in the {side}'s positions CSV with a new value from frame {i + 1}, or check the rows' order)")


def sparse_reference(reference: np.ndarray, radius: float, unit: str) -> str | None:
    """Why a radius of ``radius`` is tight for the reference positions ``reference [N, P]``: below :data:`SPARSE`
    times the reference's frame spacing (:func:`below_spacing`), each query has at most one correct reference;
    None otherwise."""
    said = below_spacing(reference, radius, unit)
    return f"the radius {radius:g} {unit} is {said}" if said else None


def below_spacing(reference: np.ndarray, radius: float, unit: str) -> str | None:
    """How ``radius`` compares with the reference's frame spacing (:func:`spacing_share`) when below :data:`SPARSE`
    times it ("below the reference's frame spacing (...): each query has at most one correct reference ..." and the
    hint; at most half of it, a query between two frames may have none); None otherwise."""
    found = spacing_share(reference, radius)
    if found is None:
        return None
    share, gap = found
    return (f"{share} the reference's frame spacing ({gap:.3g} {unit} between neighbouring frames, median): each "
            "query has at most one correct reference" +
            (", and one between two reference frames may have none" if share == "at most half" else "") +
            f" ({radius_hint(gap)})")


def spacing_share(reference: np.ndarray, radius: float, low: float = 0.0) -> tuple[str, float] | None:
    """``(share, gap)`` when ``radius`` lies from ``low`` to :data:`SPARSE` times the frame spacing ``gap``
    (:func:`seqnet.data.spacing.spacing` of ``reference [N, P]``): ``share`` is ``"at most half"`` or ``"below"``;
    None otherwise (the one rule of the radius-below-spacing lines)."""
    gap = spacing(reference)
    if not (radius > 0 and np.isfinite(gap)) or not low * gap <= radius < SPARSE * gap:
        return None
    return ("at most half" if radius <= 0.55 * gap else "below"), gap


def radius_hint(gap: float) -> str:
    """The hint for a radius below the reference's frame spacing ``gap``: a round radius of at least it."""
    return f"hint: a radius of at least the spacing is usual, e.g. --radius {math.ceil(float(f'{gap:.2g}')):g} or more"


def radius_at_spacing(reference: np.ndarray, query: np.ndarray, radius: float, unit: str) -> str | None:
    """Why the positives at ``radius`` hang on rounding: it lies within :data:`AT_MULTIPLE` times the frame spacing
    ``gap`` of ``reference [N, P]`` from 1 or 2 times ``gap``, and at least :data:`EDGE_SHARE` of ``query [M, P]``
    have a reference within :data:`EDGE` ``gap`` of the radius (frames on a regular grid: the neighbour sits at the
    radius itself, in or out by a millimetre); None otherwise, and for frame numbers (whose radii are whole frames by
    design)."""
    gap = spacing(reference)
    if unit == "frames" or not (radius > 0 and np.isfinite(gap) and gap > 0) or not len(query):
        return None
    times = round(radius / gap)
    if times not in (1, 2) or abs(radius - times * gap) > AT_MULTIPLE * gap:
        return None
    from scipy.spatial import cKDTree

    tree, q = cKDTree(np.asarray(reference, np.float64)), np.asarray(query, np.float64)
    lo, hi = radius - EDGE * gap, radius + EDGE * gap
    inner, outer = (tree.query_ball_point(q, r, return_length=True) for r in (lo, hi))
    at = outer > inner
    edge = float(np.mean(at))
    if edge < EDGE_SHARE:
        return None
    return (f"the radius {radius:g} {unit} matches {('', 'twice ')[times - 1]}the reference's frame spacing "
            f"({gap:.4g} {unit} between neighbouring frames, median) and {edge:.0%} of the queries have a reference "
            f"at the radius itself ({lo:.4g}..{hi:.4g} {unit} away): whether it is a positive hangs on the positions' "
            f"rounding ({int(inner[at].min())} to {int(outer[at].max())} positives per query across that band; hint: "
            f"a radius between whole multiples of the spacing, e.g. --radius {(times + 0.5) * gap:.3g})")


def route_checks(ds: Dataset, radius: float | None = None, sequence: bool = True, view: bool = False) -> list[str]:
    """The lines of this module's checks on ``ds`` (``radius``: the one evaluated, default ``ds.radius``; ``view``:
    ``ds`` is an evaluated split, its rows numbered from the split's first, which the lines say), for real
    positions only (not frame numbers beside explicit positives): a standstill of either side (its share of each
    named split), jumps inside a sequence (only when ``sequence`` methods are concerned), both for a side in route
    order (:func:`seqnet.data.spacing.out_of_order` says the other) without a frozen GPS fix (whose catch-up is no
    gap: :func:`seqnet.data.sanity.truth.frozen_positions` says it) and in distance units (frame numbers skip frames
    without moving: Nordland's stops left out), a radius below the reference's spacing or at a multiple of it
    (without explicit positives)."""
    if ds.positives is not None and ds.position_unit == "frames":
        return []
    unit, name = ds.position_unit, ds.name if view else ""
    found = []
    for side, t in (("query", ds.query), ("reference", ds.reference)):
        parts = {f"split {split}'s {side} rows" if side == "reference" else f"split {split}'s queries":
                 ds.ranges(split)[side] for split in ds.splits}
        if unit != "frames" and not (out_of_order(t.positions, t.seq_bounds, ds.radius, unit, side) or
                                     frozen_positions(t.positions, t.descriptors, side)):
            found += [standstill(t, unit, side, parts, thin_hint(ds), name),
                      position_jumps(t, unit, side, name) if sequence else None]
    if ds.positives is None:
        r = ds.radius if radius is None else radius
        found += [sparse_reference(ds.reference.positions, r, unit),
                  radius_at_spacing(ds.reference.positions, ds.query.positions, r, unit)]
    return [line for line in found if line]
