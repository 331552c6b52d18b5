"""The checks of an evaluated route that say the user probably meant something else (one line each, logged
and kept in the results' ``warnings`` by ``seqnet eval``): a query sequence driven opposite to the reference
(:func:`reversed_route`), a near-trivial ground truth (:func:`trivial_truth`), and, through
:func:`route_warnings`, rows out of route order (names in text order: :func:`seqnet.data.order.frame_order_lines`),
different sampling rates and duplicated query rows."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from ..core.tensors import spread
from ..data.order import frame_order_lines
from ..data.sanity import copied_queries, duplicated_rows, real_positions, route_order, transposed_descriptors
from ..data.sanity.positions import copied_positions
from ..data.sanity.revisits import revisited_reference
from ..data.sanity.route import route_checks
from ..data.sanity.spaces import foreign_spaces, separate_pcas
from ..data.sanity.truth import degree_positions
from ..data.sanity.values import narrow_directions
from ..data.spacing import RATE_RATIO, step_rates, unequal_steps
from ..metrics.inputs import trivial_truth  # noqa: F401 - re-exported (methods.checks)
from .grammar import parse_method

REVERSED_BELOW = -0.5  # the correlation of the query's and its positives' frame order below which a route runs back


def route_direction(truth: Any, samples: int = 200, rows: tuple[int, int] | None = None) -> float | None:
    """The correlation of query items' indices with their correct references' indices: near 1 when the query
    traverse runs the way the reference does, near −1 when it runs back; None with fewer than 3 pairs or no
    spread. Explicit positives: every pair; a radius: the nearest reference of ``samples`` evenly spaced queries
    when it is within the radius (numpy only, one query at a time: bounded memory). ``rows``: only the query
    items ``a:b`` (one sequence)."""
    a, b = rows if rows is not None else (0, len(truth.q_pos))
    if truth.positives is not None:
        q, r = truth.positives.pairs()
        q, r = q[(q >= a) & (q < b)], r[(q >= a) & (q < b)]
    elif len(truth.r_pos) == 0 or b <= a:
        return None
    else:
        items = a + spread(b - a, samples)
        near = np.array([np.square(truth.r_pos - truth.q_pos[i]).sum(axis=1).argmin() for i in items], np.int64)
        close = np.square(truth.r_pos[near] - truth.q_pos[items]).sum(axis=1) <= truth.radius**2
        q, r = items[close], near[close]
    if len(q) < 3 or np.ptp(q) == 0 or np.ptp(r) == 0:
        return None
    return float(np.corrcoef(q.astype(np.float64), r.astype(np.float64))[0, 1])


LEG_SAMPLES = 4000  # query items looked at for backward legs within a sequence (evenly spaced), at most


def _matched_refs(truth: Any, items: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The query items of ``items [S]`` with a correct reference, and for each its reference index: the mean of its
    positives, or its nearest reference when within the radius (a k-d tree: O(S log R))."""
    if truth.positives is not None:
        q, r = truth.positives.pairs()
        n = len(truth.q_pos)
        count = np.bincount(q, minlength=n)[items]
        mean = np.bincount(q, weights=r.astype(np.float64), minlength=n)[items] / np.maximum(count, 1)
        return items[count > 0], mean[count > 0]
    dist, near = nearest_position(np.asarray(truth.r_pos), np.asarray(truth.q_pos)[items])
    close = dist <= truth.radius
    return items[close], near[close].astype(np.float64)


def nearest_position(r_pos: np.ndarray, q_pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(distance [S], index [S])`` of the nearest row of ``r_pos [R, P]`` (R ≥ 1) to each of ``q_pos [S, P]``: for
    one coordinate (frame numbers) a sorted search (:func:`nearest_1d`: no scipy on the plain NumPy route), else a
    k-d tree."""
    if r_pos.shape[1] == 1:
        return nearest_1d(r_pos[:, 0], q_pos[:, 0])
    from scipy.spatial import cKDTree

    return cKDTree(r_pos).query(q_pos, k=1)


def nearest_1d(ref: np.ndarray, query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(distance [S], index [S])`` of the nearest of ``ref [R]`` (R ≥ 1, any order) to each of ``query [S]``
    (ties: the lower index of the sorted values). O((R + S) log R)."""
    order = np.argsort(ref, kind="stable")
    srt = ref[order]
    at = np.clip(np.searchsorted(srt, query), 1, len(srt) - 1) if len(srt) > 1 else np.zeros(len(query), np.int64)
    lo, hi = srt[np.maximum(at - 1, 0)], srt[at]
    pick = np.where(np.abs(query - lo) <= np.abs(hi - query), np.maximum(at - 1, 0), at)
    return np.abs(srt[pick] - query), order[pick]


def window_correlations(q: np.ndarray, r: np.ndarray, w: int) -> np.ndarray:
    """``[S - w + 1]``: the correlation of ``q [S]`` and ``r [S]`` over each window of ``w`` consecutive entries
    (0 where either is constant in the window: a stop)."""
    from numpy.lib.stride_tricks import sliding_window_view

    qs, rs = (sliding_window_view(np.asarray(v, dtype=np.float64), w) for v in (q, r))
    qc, rc = qs - qs.mean(axis=1, keepdims=True), rs - rs.mean(axis=1, keepdims=True)
    den = np.sqrt((qc * qc).sum(axis=1) * (rc * rc).sum(axis=1))
    return np.where(den > 0, (qc * rc).sum(axis=1) / np.where(den > 0, den, 1.0), 0.0)


def backward_legs(truth: Any, runs: Sequence[tuple[int, int]]) -> list[tuple[int, int, float, float]]:
    """The runs of query items within each of ``runs`` (``a:b``, a sequence that as a whole runs forward) whose
    correct references go back: ``(first item, last item + 1, reference at its start, at its end)`` each, from the
    farthest reference of the run to its nearest. Over at most
    :data:`LEG_SAMPLES` evenly spaced items with a correct reference per sequence, a window of ``w`` of them (1/25
    of them, at least 8) is backward when the correlation of item and reference index in it is below
    :data:`REVERSED_BELOW`; a run of overlapping backward windows is a leg when it spans ``2 w`` items and its
    reference goes back by at least ``w / 2`` frames (a stop's jitter does neither). One matching pass serves every
    sequence (:func:`legs_of` each); O(S w), ``w`` bounded by the samples: O(S)."""
    runs = [(a, b) for a, b in runs if b - a >= 16]
    if not runs or len(truth.r_pos) == 0:
        return []
    q, r = _matched_refs(truth, np.unique(np.concatenate([a + spread(b - a, LEG_SAMPLES) for a, b in runs])))
    cuts = np.searchsorted(q, np.asarray(runs).ravel())  # sliced per run
    return [leg for lo, hi in cuts.reshape(-1, 2) for leg in legs_of(q[lo:hi], r[lo:hi])]


def legs_of(q: np.ndarray, r: np.ndarray) -> list[tuple[int, int, float, float]]:
    """The backward legs of one sequence's sampled query items ``q [S]`` (ascending) with a correct reference,
    and each one's reference index ``r [S]``."""
    w = max(8, len(q) // 25)
    if len(q) < 2 * w:
        return []
    back = np.concatenate([[False], window_correlations(q, r, w) < REVERSED_BELOW, [False]])
    starts, ends = np.flatnonzero(~back[:-1] & back[1:]), np.flatnonzero(back[:-1] & ~back[1:])
    legs = []
    for s, e in zip(starts, ends, strict=True):  # windows s..e-1 cover samples s .. e-1+w-1
        last = e - 1 + w - 1
        top, low = s + int(np.argmax(r[s:last + 1])), s + int(np.argmin(r[s:last + 1]))  # the turns
        if last - s + 1 >= 2 * w and low > top and r[top] - r[low] >= w / 2:
            legs.append((int(q[top]), int(q[low]) + 1, float(r[top]), float(r[low])))
    return legs


def sequences(bounds: np.ndarray | None, items: np.ndarray) -> dict[tuple[int, int], tuple[int, int]]:
    """The half-open range of evaluated items (``items [M]``: ascending query frames) in each query sequence,
    by the sequence's frames (``bounds [N, 2]``: the half-open sequence of every frame; None: one sequence)."""
    whole = {(0, len(items)): (0, len(items))}
    if bounds is None or len(bounds) == 0:
        return whole
    seqs = np.unique(np.asarray(bounds), axis=0)
    at = np.searchsorted(items, seqs)
    return {(int(s), int(e)): (int(a), int(b)) for (s, e), (a, b) in zip(seqs, at, strict=True) if b > a} or whole


def reversed_route(truth: Any, methods: Iterable[str], bounds: np.ndarray | None = None,
                   items: np.ndarray | None = None) -> str | None:
    """Why forward sequence methods among ``methods`` cannot match a query traverse (or, with several query
    sequences, ``bounds [N, 2]`` of the query frames, some of them) that runs opposite to the reference
    (:func:`route_direction` below :data:`REVERSED_BELOW`), and what to use; None otherwise. ``items [M]``: the
    query frame of each of the truth's items (default: item i is frame i)."""
    forward = [n for n in methods if not parse_method(n).single_frame and not n.endswith("-rev")]
    if not forward:
        return None
    frames = np.arange(len(truth.q_pos)) if items is None else np.asarray(items)
    runs = sequences(bounds, frames)
    corr = {seq: route_direction(truth, rows=r) for seq, r in runs.items()}
    back = [(seq, c) for seq, c in corr.items() if c is not None and c < REVERSED_BELOW]
    named = f"{', '.join(forward[:4])}{' ...' if len(forward) > 4 else ''}"
    if not back:
        return backward_leg_line(truth, list(runs.values()), frames, named)
    if len(back) == len(runs):  # the whole traverse (one sequence, or every one)
        whole = route_direction(truth) if len(runs) > 1 else None
        whole = back[0][1] if whole is None else whole
        return (f"the query traverse runs opposite to the reference: its correct references go back as it goes on "
                f"(correlation {whole:.2f}), so the sequence methods {named} compare frames in the wrong "
                "order; use the reversed matchers (e.g. raw+seqmatch-rev) or give the query frames in the "
                "opposite order")
    which = ", ".join(f"{a}:{b} (correlation {c:.2f})" for (a, b), c in back[:6])
    return (f"{len(back)} of the {len(runs)} query sequences run opposite to the reference (query frames {which}"
            f"{' ...' if len(back) > 6 else ''}): their correct references go back as they go on, so the sequence "
            f"methods {named} compare their frames in the wrong order; evaluate them apart with the reversed "
            "matchers (e.g. raw+seqmatch-rev) or give their frames in the opposite order")


def backward_leg_line(truth: Any, runs: list[tuple[int, int]], frames: np.ndarray, named: str) -> str | None:
    """The line for query sequences (item ranges ``runs``) that run forward as a whole but hold a leg whose correct
    references go back (:func:`backward_legs`: an out-and-back drive in one sequence); ``frames [M]``: each item's
    query frame. None when there is none."""
    legs = backward_legs(truth, runs)
    if not legs:
        return None
    which = ", ".join(f"{int(frames[a])}:{int(frames[b - 1]) + 1} (references {r0:.0f} back to {r1:.0f})"
                      for a, b, r0, r1 in legs[:4])
    return (f"query frames {which}{' ...' if len(legs) > 4 else ''} run opposite to the reference within a query "
            f"sequence that otherwise runs forward: there the sequence methods {named} compare frames in the wrong "
            "order; split the traverse into sequences at the turns (a sequence column in the query's CSV) and "
            "evaluate the backward ones with the reversed matchers (e.g. raw+seqmatch-rev), or use raw+graph")


def route_warnings(ds: Any, truth: Any, items: np.ndarray, methods: Iterable[str]) -> list[str]:
    """Every line of this module's checks on an evaluation: ``ds`` the evaluated split (re-sampled as asked;
    None: only the truth's checks), ``truth`` over its query frames ``items [M]``, for ``methods``: reversed
    sequences, trivial truth, rows out of route order and different sampling rates (for real positions, when a
    sequence method is evaluated), duplicated rows of either side, queries that are copies of references,
    positions in degrees taken as metres, the reference's positions given for the query, a reference that passes
    places twice unknown to the ground truth, square descriptors that may be transposed (of the whole dataset the
    split is of), rows sharing a common offset far beyond their spread, a query not comparable with the reference
    (two models, a PCA per traverse) (:mod:`seqnet.data.sanity`: said at build,
    and here for a dataset built before or by other means)."""
    methods = list(methods)
    if ds is None:
        return [line for line in (reversed_route(truth, methods), trivial_truth(truth)) if line]
    q, r = ds.query, ds.reference
    found = [reversed_route(truth, methods, q.seq_bounds, items), trivial_truth(truth)]
    parsed = [parse_method(n) for n in methods]
    if real_positions(ds) and any(not m.single_frame for m in parsed):
        disorder = route_order(ds)
        rates = any(m.rate_sensitive for m in parsed) and step_rates(q.positions, q.seq_bounds, r.positions,
                                                                     r.seq_bounds, ds.position_unit)
        found += disorder or [rates or None]
    elif ds.positives is not None and any(m.rate_sensitive for m in parsed):
        found.append(positives_rates(ds))
    found += [f"{ds.name}: {line}" for line in frame_order_lines(ds)]  # frame-index truth: names show the order
    found += [duplicated_rows(q.descriptors, "query"), duplicated_rows(r.descriptors, "reference"),
              copied_queries(ds), None if found[1] else degree_positions(ds), copied_positions(ds),
              revisited_reference(ds), *transposed_descriptors(ds.source[0] if ds.source is not None else ds),
              narrow_directions(ds), separate_pcas(ds) or foreign_spaces(ds)]
    found += route_checks(ds, truth.radius, any(not m.single_frame for m in parsed), view=True)  # stops, jumps
    return [line for line in found if line]


def positives_rates(ds: Any) -> str | None:
    """The :func:`seqnet.data.spacing.step_rates` line of a dataset whose explicit positives are its only
    geometry (positions are frame numbers): the step of the mean positive reference between consecutive query
    frames that both have positives (a trimmed mean: reference frames per query frame; 1: equal rates), e.g. 2 after
    ``--resample-every 2 --resample-side query`` of traverses recorded at equal rates; None within
    :data:`~seqnet.data.spacing.RATE_RATIO` either way or with fewer than 3 such steps."""
    q, r = ds.positives.pairs()
    n = len(ds.query)
    count = np.bincount(q, minlength=n)
    has = np.flatnonzero(count)
    if len(has) < 4:
        return None
    centre = np.bincount(q, weights=r.astype(np.float64), minlength=n)[has] / count[has]
    near = np.diff(has) == 1  # consecutive query frames: a sequence's jump or a gap is no step
    step = np.sort(np.abs(np.diff(centre))[near])
    if len(step) < 3:
        return None
    cut = len(step) // 10  # a trimmed mean: steps of whole frames (0, 1, 0, 1 at half rate) average right
    rate = float(step[cut:len(step) - cut].mean())
    if rate <= 0 or max(rate, 1 / rate) <= RATE_RATIO:
        return None
    done = "".join(f", after --resample-every {d['every']} --resample-side {d['side']}"
                   for d in ds.extra.get("resample", [])[-1:])
    dense = "query" if rate < 1 else "reference"
    return (f"the query advances {rate:.2g} reference frames per query frame (the mean step of its explicit "
            f"positives{done}): {unequal_steps(round(max(rate, 1 / rate)), dense)}")
