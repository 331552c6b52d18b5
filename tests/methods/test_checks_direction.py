"""A query traverse that runs opposite to the reference is named, with the reversed matchers to use."""

from __future__ import annotations

import logging

import numpy as np

from seqnet.cli import main as cli_main
from seqnet.data.positives import Positives
from seqnet.methods.checks import reversed_route, route_direction
from seqnet.metrics.recall import GroundTruth


def test_the_direction_of_the_route():
    n = 40
    forward = GroundTruth(np.arange(n)[:, None], np.arange(n)[:, None], 1.0)
    back = GroundTruth(np.zeros((n, 1)), np.zeros((n, 1)), 1.0, Positives.from_lists([[n - 1 - i] for i in range(n)]))
    assert route_direction(forward) > 0.9 and route_direction(back) < -0.99
    assert reversed_route(forward, ["raw+seqmatch"]) is None
    said = reversed_route(back, ["single", "raw+seqmatch", "raw+seqmatch-rev"])
    assert "runs opposite" in said and "raw+seqmatch-rev" in said and "methods raw+seqmatch compare" in said
    assert reversed_route(back, ["single", "s1"]) is None  # single frames: the order does not matter
    assert route_direction(GroundTruth(np.zeros((1, 1)), np.zeros((2, 1)), 1.0)) is None  # 2 pairs


def test_eval_warns_on_a_reversed_query(tmp_path, caplog):
    from seqnet.data.io import save_dataset
    from seqnet.data.synth import make_synthetic
    from seqnet.data.traverse import Dataset

    ds = make_synthetic(places=120, dim=16, seed=2, noise=0.2)
    q = ds.query
    back = q.__class__(q.descriptors[::-1].copy(), q.positions[::-1].copy(), name="winter-back")
    path = save_dataset(Dataset(back, ds.reference, ds.radius), tmp_path / "back")
    caplog.set_level(logging.WARNING, logger="seqnet")
    assert cli_main(["eval", "--dataset", str(path), "--split", "all", "--method", "single,raw+seqmatch",
                     "--seq-len", "3", "--json", str(tmp_path / "r.json"), "--device", "cpu"]) == 0
    assert any("runs opposite to the reference" in r.getMessage() for r in caplog.records)
    caplog.clear()
    path = save_dataset(Dataset(ds.query, ds.reference, ds.radius), tmp_path / "fwd")
    assert cli_main(["eval", "--dataset", str(path), "--split", "all", "--method", "single,raw+seqmatch",
                     "--seq-len", "3", "--device", "cpu"]) == 0
    assert not any("runs opposite" in r.getMessage() for r in caplog.records)


def test_no_reference_or_no_query_has_no_direction():
    assert route_direction(GroundTruth(np.zeros((0, 1)), np.zeros((5, 1)), 1.0)) is None
    assert route_direction(GroundTruth(np.zeros((4, 1)), np.zeros((0, 1)), 1.0)) is None


def test_a_ground_truth_that_makes_every_answer_right_is_named():
    from seqnet.methods.checks import trivial_truth

    same = GroundTruth(np.zeros((30, 2)), np.zeros((40, 2)), 5.0)  # constant positions
    said = trivial_truth(same)
    assert "100% of the 40 references" in said and "within the radius 5" in said
    route = GroundTruth(np.arange(30.0)[:, None], np.arange(40.0)[:, None], 1.0)
    assert trivial_truth(route) is None
    wide = Positives.from_lists([list(range(30)) for _ in range(10)])
    assert "as its positives" in trivial_truth(GroundTruth(np.zeros((10, 1)), np.zeros((40, 1)), 1.0, wide))
