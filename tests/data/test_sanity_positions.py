"""The reference's positions given for the query too (seqnet.data.sanity.positions): said when the images show
other places at the same rows; silent for traverses recorded in sync that share one track."""

from __future__ import annotations

import numpy as np

from seqnet.data.positives import Positives
from seqnet.data.sanity import dataset_warnings
from seqnet.data.sanity.positions import copied_positions, own_row_rank
from seqnet.data.traverse import Dataset, Traverse


def drive(shift: int, n: int = 60, same_positions: bool = True, **kw) -> Dataset:
    """Places 10 m apart; the query's images start ``shift`` places later; its positions: the reference's
    (``same_positions``) or its own, with 1 m noise."""
    rng = np.random.default_rng(2)
    place = rng.standard_normal((n + shift, 16))
    ref = (place[:n] + 0.3 * rng.standard_normal((n, 16))).astype(np.float32)
    qry = (place[shift:] + 0.3 * rng.standard_normal((n, 16))).astype(np.float32)
    r_pos = np.c_[500000 + 10.0 * np.arange(n), 7000000 + 30 * np.sin(np.arange(n) / 40)]
    q_pos = r_pos.copy() if same_positions else r_pos + 10.0 * shift + rng.normal(0, 1, r_pos.shape)
    return Dataset(Traverse(ref, r_pos, [f"f{i:04d}.png" for i in range(n)], name="reference"),
                   Traverse(qry, q_pos, [f"f{i:04d}.png" for i in range(n)], name="query"), 12.0, name="d", **kw)


def test_the_reference_positions_given_for_the_query_are_said():
    [line] = dataset_warnings(drive(15))
    assert line.startswith("d: the query positions are the reference positions, row for row (all 60 equal), but the "
                           "images disagree: the reference image of a query's own row is farther from it than ")
    assert line.endswith("the same positions file given for both traverses? (hint: give the query traverse's own "
                         "positions, e.g. --query-csv)")


def test_synchronised_traverses_sharing_one_track_stay_silent():
    assert dataset_warnings(drive(0)) == []  # Nordland's seasons: one GPS track for frame-synchronised videos
    assert dataset_warnings(drive(15, same_positions=False)) == []  # own positions: nothing to say here
    assert copied_positions(drive(15, positives=Positives.from_lists([[i] for i in range(60)]))) is None
    ds = drive(15)
    frames = Dataset(ds.reference, ds.query, 1.0, position_unit="frames", name="d")
    assert copied_positions(frames) is None  # frame-aligned: equal frame numbers by design


def test_own_row_rank_vs_a_loop():
    ds = drive(15)
    got = own_row_rank(ds, samples=200)
    unit = [t.descriptors / np.linalg.norm(t.descriptors, axis=1, keepdims=True) for t in (ds.query, ds.reference)]
    shares = []
    for i in range(60):
        d_own = np.linalg.norm(unit[0][i] - unit[1][i])
        far = [j for j in range(60) if np.linalg.norm(ds.query.positions[i] - ds.reference.positions[j]) > 12.0]
        shares.append(np.mean([np.linalg.norm(unit[0][i] - unit[1][j]) < d_own for j in far]))
    assert abs(got - np.median(shares)) < 1e-9
    assert got > 0.3 and own_row_rank(drive(0)) < 0.05


def test_clean_synthetic_dataset_is_silent(synth_dataset):
    assert copied_positions(synth_dataset) is None


def test_positions_in_kilometres_are_named_not_constant_gps():
    ds = drive(0, same_positions=False)
    km = Dataset(Traverse(ds.reference.descriptors, ds.reference.positions / 1000, ds.reference.names),
                 Traverse(ds.query.descriptors, ds.query.positions / 1000, ds.query.names), 12.0, name="d")
    [line] = dataset_warnings(km)
    assert "so R@K is 1 trivially (hint: the positions advance steadily, 0.01 per row (median), so the GPS is not " \
           "constant: positions in kilometres? multiply them by 1000, or give the radius in their unit (--radius " \
           "0.012))" in line
    frozen = np.full((60, 2), 5.0)
    still = Dataset(Traverse(ds.reference.descriptors, frozen, ds.reference.names),
                    Traverse(ds.query.descriptors, frozen, ds.query.names), 12.0, name="d")
    assert "(hint: check the positions: constant GPS?)" in dataset_warnings(still)[0]
    n = np.arange(60, dtype=float)[:, None]
    frames = Dataset(Traverse(ds.reference.descriptors, n, ds.reference.names),
                     Traverse(ds.query.descriptors, n, ds.query.names), 60.0, name="d")
    assert ("(hint: the frame numbers advance 1 per row, and the radius 60 frames covers the whole route: a radius "
            "of 1-3 frames)") in " ".join(dataset_warnings(frames))


def test_a_short_route_in_metres_inside_a_large_radius_is_not_called_kilometres():
    """Frames 2 m apart over 50 m, radius 100 m: the positions are metres, the radius too large (the kilometres
    hint, with --radius 0.1, was wrong)."""
    ds = drive(0, same_positions=False)
    n = len(ds.reference)
    line = np.c_[np.arange(n) * 2.0, np.zeros(n)]
    short = Dataset(Traverse(ds.reference.descriptors, line, ds.reference.names),
                    Traverse(ds.query.descriptors, line + 0.3, ds.query.names), 1000.0, name="d")
    said = " ".join(dataset_warnings(short))
    assert "kilometres" not in said and "a radius near the frame spacing (e.g. --radius 2)" in said, said
