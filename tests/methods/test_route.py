"""The evaluated route's warnings (seqnet.methods.route): a reversed query sequence among forward ones, rows out
of route order, different sampling rates and duplicated query rows, each one line; none on real Nordland64 frames
in order."""

from __future__ import annotations

import numpy as np
from conftest import shared_data

from seqnet.data.positives import Positives
from seqnet.data.traverse import Dataset, Traverse
from seqnet.methods.route import backward_legs, reversed_route, route_warnings, sequences, window_correlations
from seqnet.metrics.recall import GroundTruth

METHODS = ["single", "raw+seqmatch"]


def two_sequences(back_second: bool = True) -> tuple[GroundTruth, np.ndarray]:
    """A query of two 150-frame sequences over a 300-frame reference, the second driven back (or forward)."""
    fwd = np.arange(150, 300, dtype=float)
    q = np.concatenate([np.arange(150.0), fwd[::-1] if back_second else fwd])[:, None]
    return GroundTruth(q, np.arange(300.0)[:, None], 1.0), np.repeat([[0, 150], [150, 300]], 150, axis=0)


def test_a_reversed_sequence_among_forward_ones_is_named():
    truth, bounds = two_sequences()
    whole = reversed_route(truth, METHODS)  # one sequence: no clear direction as a whole, but a backward leg
    assert whole.startswith("query frames 150:300 (references 299 back to 150) run opposite to the reference within")
    said = reversed_route(truth, METHODS, bounds)
    assert said.startswith("1 of the 2 query sequences run opposite") and "query frames 150:300" in said
    assert reversed_route(two_sequences(False)[0], METHODS, two_sequences(False)[1]) is None
    assert reversed_route(truth, ["single"], bounds) is None


def test_sequences_map_frames_to_evaluated_items():
    items = np.array([2, 3, 4, 152, 153])  # windows leave the ends of each sequence out
    bounds = np.repeat([[0, 150], [150, 300]], 150, axis=0)
    assert sequences(bounds, items) == {(0, 150): (0, 3), (150, 300): (3, 5)}
    assert sequences(None, items) == {(0, 5): (0, 5)}
    truth, _ = two_sequences()
    sub = GroundTruth(truth.q_pos[items], truth.r_pos, 1.0)
    assert reversed_route(sub, METHODS, bounds, items) is None  # two items: too few to tell a direction


def test_every_sequence_reversed_keeps_the_whole_traverse_message():
    q = np.arange(300.0)[::-1, None]
    said = reversed_route(GroundTruth(q, np.arange(300.0)[:, None], 1.0), METHODS,
                          np.repeat([[0, 150], [150, 300]], 150, axis=0))
    assert said.startswith("the query traverse runs opposite to the reference") and "-1.00" in said


def dataset(q_pos: np.ndarray, r_pos: np.ndarray, radius: float = 1.0, q_desc=None, **kw) -> Dataset:
    rng = np.random.default_rng(0)
    q_desc = rng.random((len(q_pos), 8), dtype=np.float32) if q_desc is None else q_desc
    return Dataset(Traverse(rng.random((len(r_pos), 8), dtype=np.float32), r_pos, name="reference"),
                   Traverse(q_desc, q_pos, name="query"), radius, name="d", **kw)


def test_route_warnings_name_shuffles_rates_and_duplicates():
    r = np.arange(300.0)[:, None]
    shuffled = dataset(np.random.default_rng(1).permutation(r), r)
    said = route_warnings(shuffled, GroundTruth(shuffled.query.positions, r, 1.0), np.arange(300), METHODS)
    assert len(said) == 1 and "not be in route order" in said[0]
    assert route_warnings(shuffled, GroundTruth(shuffled.query.positions, r, 1.0), np.arange(300), ["single"]) == []
    slow = dataset(np.arange(0, 300, 0.5)[:, None], r)
    said = route_warnings(slow, GroundTruth(slow.query.positions, r, 1.0), np.arange(600), METHODS)
    assert len(said) == 1 and "ratio 0.5" in said[0]
    truth = GroundTruth(slow.query.positions, r, 1.0)
    for robust in (["single", "raw+vseqmatch"], ["s1+graph", "hvpr-single:raw+vseqmatch"]):  # they follow the rate
        assert route_warnings(slow, truth, np.arange(600), robust) == []
    for sensitive in (["raw+vseqmatch", "seqnet"], ["hvpr-seqnet:s1+vseqmatch"], ["delta+graph"]):  # S_L / delta steps
        assert len(route_warnings(slow, truth, np.arange(600), sensitive)) == 1, sensitive
    dup = dataset(r, r, q_desc=np.ones((300, 8), np.float32))
    said = route_warnings(dup, GroundTruth(r, r, 1.0), np.arange(300), METHODS)
    assert len(said) == 1 and said[0].startswith("299 of the 300 query rows are exact duplicates")


def test_explicit_positives_of_frame_positions_give_the_rate_from_the_positives():
    """Frame numbers say nothing of steps; the positives do: a query at twice the reference's rate (each
    reference frame the positive of two query frames) is said with its ratio and the side to re-sample, a query
    at the reference's rate (±1 frame positives) is not, and frame-wise methods are never warned."""
    r, q = np.arange(300.0)[:, None], np.arange(0, 300, 0.5)[:, None]
    pos = Positives.from_lists([[int(i)] for i in q[:, 0]])
    ds = dataset(q, r, positives=pos, position_unit="frames")
    [said] = route_warnings(ds, GroundTruth(q, r, 1.0, pos), np.arange(600), METHODS)
    assert said.startswith("the query advances 0.5 reference frames per query frame (the mean step of its explicit "
                           "positives): SeqMatch-style matchers assume both traverses advance by equal steps")
    assert said.endswith("(--resample-every 2 --resample-side query)")
    assert route_warnings(ds, GroundTruth(q, r, 1.0, pos), np.arange(600), ["single"]) == []
    even = Positives.from_lists([[j for j in (i - 1, i, i + 1) if 0 <= j < 300] for i in range(300)])
    ds = dataset(r, r, positives=even, position_unit="frames")
    assert route_warnings(ds, GroundTruth(r, r, 1.0, even), np.arange(300), METHODS) == []


def test_a_resampled_query_of_explicit_positives_is_said_with_the_resampling():
    """``eval --resample-every 2 --resample-side query`` on traverses at equal rates: the line names the
    re-sampling and the now denser reference side."""
    from seqnet.data.resample import resample_dataset

    r = np.arange(300.0)[:, None]
    even = Positives.from_lists([[j for j in (i - 1, i, i + 1) if 0 <= j < 300] for i in range(300)])
    ds = resample_dataset(dataset(r, r, positives=even, position_unit="frames"), 2, "query")
    [said] = route_warnings(ds, GroundTruth(ds.query.positions, r, 1.0, ds.positives), np.arange(150), METHODS)
    assert said.startswith("the query advances 2 reference frames per query frame (the mean step of its explicit "
                           "positives, after --resample-every 2 --resample-side query): ")
    assert said.endswith("(--resample-every 2 --resample-side reference)")


def test_real_nordland64_frames_in_order_warn_nothing():
    from seqnet.data.sanity import dataset_warnings
    from seqnet.pipelines.nordland64 import list_places
    from seqnet.security.pictures import read_image

    data = shared_data("nordland64")
    names, pos = list_places(data)
    names, pos = names[:300], np.asarray(pos[:300], dtype=float)[:, None]
    summer, winter = ([read_image(data / s / n).astype(np.float32).ravel() for n in names]
                      for s in ("summer", "winter"))
    ds = Dataset(Traverse(np.stack(summer), pos, name="reference"), Traverse(np.stack(winter), pos, name="query"),
                 2.0, position_unit="frames", name="nordland64")
    truth = GroundTruth(pos, pos, 2.0)
    assert route_warnings(ds, truth, np.arange(300), METHODS) == []
    assert dataset_warnings(ds) == []


def test_the_reference_given_as_the_query_is_said_at_evaluation(tmp_path):
    """A dataset whose query descriptors are the reference's (row for row, or each a copy of some reference row)
    scores 1.000 everywhere: the evaluation says why, as dataset building does."""
    r = np.arange(300.0)[:, None]
    same = dataset(r, r)
    same = Dataset(same.reference, Traverse(same.reference.descriptors.copy(), r, name="query"), 1.0, name="d")
    said = route_warnings(same, GroundTruth(r, r, 1.0), np.arange(300), METHODS)
    assert len(said) == 1 and "the query images are the reference images" in said[0]
    picked = np.random.default_rng(2).permutation(300)[:100]
    some = Dataset(same.reference, Traverse(same.reference.descriptors[picked], r[picked], name="query"), 1.0)
    said = route_warnings(some, GroundTruth(r[picked], r, 1.0), np.arange(100), ["single"])
    assert len(said) == 1 and "every one of the 100 query descriptors is an exact copy" in said[0]
    assert route_warnings(dataset(r, r), GroundTruth(r, r, 1.0), np.arange(300), METHODS) == []


def test_eval_of_a_copied_query_warns(synth_dir, tmp_path, caplog):
    import json
    import logging

    from seqnet.cli import main as cli_main
    from seqnet.data.io import load_dataset, save_dataset

    ds = load_dataset(synth_dir)
    copy = Dataset(ds.reference, Traverse(ds.reference.descriptors.copy(), ds.reference.positions, name="query"),
                   ds.radius, name="copy")
    save_dataset(copy, tmp_path / "copy")
    caplog.set_level(logging.WARNING, logger="seqnet")
    assert cli_main(["eval", "--dataset", str(tmp_path / "copy"), "--method", "single", "--json",
                     str(tmp_path / "r.json"), "--device", "cpu"]) == 0
    res = json.loads((tmp_path / "r.json").read_text())
    assert res["methods"]["single"]["recall@1"] == 1.0
    assert any("the query images are the reference images" in w for w in res["warnings"])
    assert any("trivially perfect" in r.getMessage() for r in caplog.records)


def test_an_out_and_back_leg_within_one_sequence_is_named():
    """Out 0..199 and back 199..100 in one sequence: the whole-traverse correlation is positive, so the return leg
    went unsaid (raw+seqmatch 0.062 on it); now its query frames are named, with positives too. A straight
    traverse, one with stops and GPS jitter, and one at half the reference's rate stay silent."""
    route = np.concatenate([np.arange(200), np.arange(199, 99, -1)]).astype(float)
    ref = np.arange(200.0)[:, None]
    said = reversed_route(GroundTruth(route[:, None], ref, 1.0), METHODS)
    assert said.startswith("query frames 199:300 (references 199 back to 100) run opposite") and "-rev" in said
    pos = Positives.from_lists([[int(p)] for p in route])
    assert backward_legs(GroundTruth(route[:, None], ref, 1.0, pos), [(0, 300)]) == [(199, 300, 199.0, 100.0)]
    rng = np.random.default_rng(0)
    stops = np.concatenate([np.arange(80), np.full(60, 80), np.arange(80, 200)]).astype(float)
    jitter = np.stack([10 * stops + rng.normal(0, 3, len(stops)), rng.normal(0, 3, len(stops))], axis=1)
    ref2 = np.stack([10 * np.arange(200.0), np.zeros(200)], axis=1)
    for q, r, radius in ((np.arange(200.0)[:, None], ref, 1.0), (jitter, ref2, 15.0),
                         (np.arange(0, 200, 0.5)[:, None], ref, 1.0)):
        assert reversed_route(GroundTruth(q, r, radius), METHODS) is None


def test_window_correlations_match_a_loop():
    rng = np.random.default_rng(1)
    q, r = np.arange(50.0), rng.normal(size=50).cumsum()
    r[10:20] = 3.0  # a stop: constant, correlation 0
    w = 8
    loop = [0.0 if np.ptp(r[i:i + w]) == 0 else np.corrcoef(q[i:i + w], r[i:i + w])[0, 1] for i in range(50 - w + 1)]
    assert np.allclose(window_correlations(q, r, w), loop)


def test_nearest_1d_is_a_naive_search():
    """The sorted search of frame numbers gives the nearest reference of a loop (the distance exactly; the index
    of a tie may differ, never its distance)."""
    from seqnet.methods.route import nearest_1d

    rng = np.random.default_rng(0)
    for n_ref in (1, 2, 7, 50):
        ref = rng.integers(0, 30, n_ref).astype(np.float64)
        query = rng.uniform(-5, 35, 40)
        dist, idx = nearest_1d(ref, query)
        naive = np.abs(query[:, None] - ref[None]).min(axis=1)
        np.testing.assert_allclose(dist, naive)
        np.testing.assert_allclose(np.abs(ref[idx] - query), naive)


def test_one_matching_pass_for_every_sequence_finds_the_legs_of_each():
    """backward_leg_line matches every sequence's samples in one pass (it rebuilt a k-d tree per sequence: 14 s on
    500 sequences of a 100k map): the same legs as backward_legs run sequence by sequence."""
    from types import SimpleNamespace

    from seqnet.methods.route import backward_leg_line, backward_legs

    r = np.c_[np.arange(400.0), np.zeros(400)]
    out_back = np.r_[np.arange(0, 120), np.arange(119, 39, -1)]  # a sequence out, then back
    q = np.r_[out_back, np.arange(200, 360)].astype(float)
    truth = SimpleNamespace(positives=None, r_pos=r, q_pos=np.c_[q, np.zeros(len(q))], radius=1.5)
    runs = [(0, 200), (200, 360)]
    per_run = [leg for run in runs for leg in backward_legs(truth, [run])]
    assert len(per_run) == 1
    a, b, r0, r1 = per_run[0]
    line = backward_leg_line(truth, runs, np.arange(len(q)), "raw+seqmatch")
    assert line.startswith(f"query frames {a}:{b} (references {r0:.0f} back to {r1:.0f})"), line
