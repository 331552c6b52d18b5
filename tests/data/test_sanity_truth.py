"""The ground-truth checks of seqnet.data.sanity.truth: square positives read better transposed, a frame radius as
wide as a metres one, a frozen GPS fix; each against a loop or a hand-made case, silent on correct data."""

from __future__ import annotations

import numpy as np
import pytest
from data.test_sanity import make

from seqnet.data.positives import Positives
from seqnet.data.sanity import dataset_warnings
from seqnet.data.sanity.truth import frozen_positions, nearest_rows, transposed_positives, wide_frame_radius


@pytest.fixture
def route():
    """60 places along a route: a random walk of descriptors (neighbours alike), seen twice with noise."""
    rng = np.random.default_rng(1)
    places = np.cumsum(rng.normal(size=(60, 16)), axis=0).astype(np.float32)
    return places, places + rng.normal(scale=0.3, size=places.shape).astype(np.float32)


def test_nearest_rows_vs_a_loop(route):
    ref, q = route
    got = nearest_rows(ref, q[::3], block=7)
    assert got.tolist() == [int(np.argmin([np.linalg.norm(r - x) for r in ref])) for x in q[::3]]


def _shifted(n: int, by: int) -> list[list[int]]:
    """Query i matches reference i - by (and its neighbours): not symmetric."""
    return [[j for j in (i - by - 1, i - by, i - by + 1) if 0 <= j < n] for i in range(n)]


def test_square_positives_given_transposed_are_warned(route):
    places, seen = route
    ref = np.roll(places, -5, axis=0)  # reference j shows place j + 5; query i shows place i
    lists = _shifted(60, 5)
    good = Positives.from_lists(lists)
    rows, cols = good.pairs()
    flipped = Positives.from_pairs(cols, rows, 60)  # [N_reference, N_query] read as [N_query, N_reference]
    assert transposed_positives(make(ref, seen, positives=good)) is None
    line = transposed_positives(make(ref, seen, positives=flipped))
    assert line.startswith("the positives read better transposed") and "query,reference" in line
    symmetric = Positives.from_lists(_shifted(60, 0))
    assert transposed_positives(make(places, seen, positives=symmetric)) is None  # both readings alike
    assert transposed_positives(make(ref[:50], seen, positives=flipped.select(np.arange(60), np.arange(50)))) is None
    assert any("read better transposed" in w for w in dataset_warnings(make(ref, seen, positives=flipped)))


def test_a_frame_radius_as_wide_as_metres_is_warned(route):
    places, seen = route
    assert wide_frame_radius(make(places, seen, radius=1.0)) is None
    line = wide_frame_radius(make(places, seen, radius=10.0))
    assert line.startswith("radius 10 frames: the median query has 21 correct references (35% of the 60)")
    assert wide_frame_radius(make(places, seen, radius=100.0)) is None  # every reference: constant positions say it
    assert wide_frame_radius(make(places, seen, radius=10.0, positives=Positives.from_lists(_shifted(60, 0)))) is None
    metres = np.c_[np.arange(60.0) * 10, np.zeros(60)]
    assert wide_frame_radius(make(places, seen, metres, metres, radius=100.0)) is None


def test_a_frozen_fix_is_warned_but_a_stopped_vehicle_is_not(route):
    places, seen = route
    pos = np.c_[np.arange(60.0) * 10, np.zeros(60)]
    frozen = pos.copy()
    frozen[20:35] = frozen[20]
    line = frozen_positions(frozen, seen, "query")
    assert line.startswith("15 consecutive query rows (20:35) share one position while their images change")
    stopped = seen.copy()
    stopped[20:35] = seen[20] + np.random.default_rng(2).normal(scale=1e-3, size=(15, 16))
    assert frozen_positions(frozen, stopped, "query") is None  # images barely change: a stop
    assert frozen_positions(pos, seen, "query") is None
    short = pos.copy()
    short[20:25] = short[20]
    assert frozen_positions(short, seen, "query") is None  # 5 rows: a pause
    lines = dataset_warnings(make(places, seen, pos, frozen, radius=15.0))
    assert [w for w in lines if "frozen GPS fix" in w] and all("reference rows" not in w for w in lines)


def test_duplicate_reference_rows_are_warned(route):
    places, seen = route
    ref = places.copy()
    ref[10:20] = ref[10]
    lines = dataset_warnings(make(ref, seen))
    assert any(w.startswith("d: 9 of the 60 reference rows are exact duplicates") for w in lines)


def test_degrees_taken_as_metres_are_warned_whatever_the_radius(route):
    from seqnet.data.sanity.truth import degree_positions

    places, seen = route
    deg = np.c_[10.39 + np.arange(60) * 1e-4, 63.43 + np.zeros(60)]
    line = degree_positions(make(places, seen, deg, deg + 1e-6, radius=0.0002))
    assert line.startswith("the positions span 0.0059 units around (10.39295, 63.43000), taken as metres with a "
                           "radius of 0.0002: positions look like degrees")
    metres = np.c_[500000 + np.arange(60) * 10.0, np.full(60, 7e6)]
    assert degree_positions(make(places, seen, metres, metres, radius=25.0)) is None
    table = np.c_[np.arange(60) * 0.01, np.zeros(60)]  # a tabletop's metres near the origin
    assert degree_positions(make(places, seen, table, table, radius=0.02)) is None
    assert degree_positions(make(places, seen, deg, deg, radius=10.0)) is None  # every one within: said elsewhere


def test_a_split_whose_ranges_share_no_place_is_warned(route):
    from seqnet.data.sanity.truth import unmatched_splits

    places, seen = route
    meant = {"train": {"reference": (0, 60), "query": (0, 20)}, "val": {"reference": (0, 60), "query": (20, 40)}}
    assert unmatched_splits(make(places, seen, splits=meant)) is None
    chunks = {"train": {"reference": (0, 20), "query": (40, 60)}, "val": {"reference": (0, 60), "query": (20, 40)}}
    line = unmatched_splits(make(places, seen, splits=chunks))
    assert line.startswith("split train (reference 0:20, queries 40:60) has no query with a true match in the split's "
                           "reference range: NAME=A:B,C:D is reference A:B and queries C:D")
    pos = Positives.from_lists(_shifted(60, 0))
    assert "split train" in unmatched_splits(make(places, seen, splits=chunks, positives=pos))


def test_a_split_against_the_whole_reference_is_named_for_what_it_lacks(route):
    """A test split NAME=A:B (the whole reference) whose queries' positives are all empty: the positives are named,
    not the range syntax (which it already uses) nor the radius (which explicit positives ignore)."""
    from seqnet.data.sanity.truth import unmatched_splits

    places, seen = route
    lists = [[i] if i < 40 else [] for i in range(60)]
    splits = {"train": {"reference": (0, 60), "query": (0, 40)}, "test": {"reference": (0, 60), "query": (40, 60)}}
    line = unmatched_splits(make(places, seen, splits=splits, positives=Positives.from_lists(lists)))
    assert line == ("split test (queries 40:60): the explicit positives list no reference for any of its queries (an "
                    "empty list is no match): it cannot be scored"), line
    assert "NAME=A:B" not in line


def test_a_matrix_given_as_descriptors_is_warned(route):
    from seqnet.data.sanity.truth import matrix_as_descriptors

    places, seen = route
    dist = np.linalg.norm(places[:, None] - places[None], axis=-1)
    for m in (np.exp(-dist / dist.mean()), dist):  # similarity (peaks on the diagonal), distance (dips there)
        line = matrix_as_descriptors(make(m.astype(np.float32), m.astype(np.float32)))
        assert line is not None and line.startswith("the reference descriptors are [60, 60], D equal to the number")
    square = np.random.default_rng(5).random((60, 60)).astype(np.float32)  # D = N by chance
    assert matrix_as_descriptors(make(square, square)) is None
    assert matrix_as_descriptors(make(places, seen)) is None
