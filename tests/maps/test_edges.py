"""A single-frame method on a map searches every reference frame, the frames where no window fits too (hunt 5 F1)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from seqnet.eval.evaluate import EvalConfig
from seqnet.eval.evaluate import main as eval_main
from seqnet.localize.config import LocalizeConfig
from seqnet.localize.localizer import replay
from seqnet.localize.replay import dataset_localizer
from seqnet.localize.stream import index_reference
from seqnet.maps import MapConfig, MapError, build, evaluate_main, load_map
from seqnet.maps.edges import EDGE_FILE, edge_frames, search_every_frame
from seqnet.methods.grammar import parse_method
from seqnet.search.ann import AnnConfig


def test_merged_search_ranks_by_distance_then_frame():
    items, edges = np.array([2, 3, 5]), np.array([0, 1, 4])
    by_item = lambda k: (np.array([[0.5, 0.7, 0.9]])[:, :k], np.array([[1, 0, -1]])[:, :k])  # noqa: E731
    by_edge = lambda k: (np.array([[0.5, 0.6, 2.0]])[:, :k], np.array([[2, 0, 1]])[:, :k])  # noqa: E731
    d, f = search_every_frame(items, edges, by_item, by_edge, 4)
    assert f.tolist() == [[3, 4, 0, 2]]  # the tie 0.5 by the lower frame; the item search's -1 is last
    np.testing.assert_allclose(d, [[0.5, 0.5, 0.6, 0.7]])
    assert edge_frames(np.array([3, 4, 6]), 7).tolist() == [0, 1, 2, 5]


@pytest.mark.parametrize(("conf", "with_models"), [
    (MapConfig(shortlist="single", rerank="raw+seqmatch", seq_len=4, window="causal", split="all"), False),
    (MapConfig(shortlist="single", seq_len=4, window="causal", split="all"), True),  # frames: S_1 (edge file)
])
def test_a_map_of_four_sequences_equals_the_dataset_for_single(synth_dataset, synth_dir, map_models, tmp_path, conf,
                                                               with_models):
    used = map_models if with_models else ()
    mp = load_map(build(conf, synth_dir, tmp_path / "map", used), "cpu")
    assert len(mp.items) == len(mp.frames) - 4 * 3  # 4 sequences, L-1 = 3 frames without a window in each
    assert (mp.path / EDGE_FILE).is_file() == with_models
    methods = [mp.config.method.name, "single"]
    econf = EvalConfig(methods=methods, seq_len=4, ks=(1, 5), window="causal", split="all")
    exact = json.loads((eval_main(econf, synth_dir, tmp_path / "e", used).path).read_text())["methods"]
    mapped = json.loads((evaluate_main(econf, synth_dir, mp.path, tmp_path / "m").path).read_text())["methods"]
    for name in methods:
        for key in ("recall@1", "recall@5", "queries", "no_positive"):
            assert mapped[name][key] == pytest.approx(exact[name][key]), (name, key)
    assert mapped["single"]["queries"] == len(synth_dataset.query)  # every query frame, as seqnet eval
    lconf = LocalizeConfig(method="single", k=7, device="cpu", split="all")
    a = list(replay(lconf.localizer(*index_reference(mp, lconf)), synth_dataset.query))
    b = list(replay(dataset_localizer(synth_dataset, mp.models, lconf), synth_dataset.query))
    assert [e.ref_frame for e in a] == [e.ref_frame for e in b]
    assert [e.confidence for e in a] == pytest.approx([e.confidence for e in b], abs=1e-6)
    assert [e.full_window for e in a] == [e.full_window for e in b]


def test_an_approximate_map_finds_the_frames_without_a_window(synth_dataset, synth_dir, tmp_path):
    conf = MapConfig(shortlist="single", rerank="raw+seqmatch", seq_len=4, window="causal", split="all",
                     ann=AnnConfig(kind="hnsw", ef_search=64))
    mp = load_map(build(conf, synth_dir, tmp_path / "map"), "cpu")
    view = mp.for_method(parse_method("single"))
    edges = edge_frames(mp.items, len(mp.frames))
    d, f = view.search("single", np.asarray(synth_dataset.reference.descriptors)[edges], 3)
    assert f[:, 0].tolist() == edges.tolist() and np.allclose(d[:, 0], 0, atol=1e-3)  # each edge frame is its own NN
    assert view.items.tolist() == list(range(len(mp.frames))) and view.windows.longest == 1
    assert len(mp.items) < len(mp.frames)  # the map itself is unchanged


def test_a_map_without_the_edge_descriptors_says_to_rebuild(synth_dir, map_models, tmp_path):
    mp = load_map(build(MapConfig(shortlist="single", seq_len=4, window="causal"), synth_dir, tmp_path / "m",
                        map_models), "cpu")
    mp.edge_shortlist = None  # as a map built before seqnet stored them
    with pytest.raises(MapError, match=r"not of the 3 frames where no window fits.*rebuild it"):
        mp.for_method(parse_method("single"))
    assert mp.for_method(mp.config.method) is mp


@pytest.mark.parametrize("explicit", [False, True])
def test_eval_index_counts_queries_correct_only_where_no_window_fits(tmp_path, explicit):
    """As ``seqnet eval`` (hunt 6 F1): a query whose correct references are all frames without an item is a failure
    of a sequence method on a map too, not a query left out without a positive."""
    from seqnet.data.io import save_dataset
    from seqnet.data.positives import Positives
    from seqnet.data.traverse import Dataset, Traverse

    rng = np.random.default_rng(0)
    place = rng.standard_normal((70, 16))
    ref, qry = ((place + 0.4 * rng.standard_normal(place.shape)).astype(np.float32) for _ in range(2))
    bounds = np.array([[0, 40]] * 40 + [[s, s + 3] for s in range(40, 70, 3) for _ in range(3)])  # 3-frame drives
    pos = np.c_[10.0 * np.arange(70), np.zeros(70)]
    positives = Positives.from_lists([[i] for i in range(70)]) if explicit else None
    ds = save_dataset(Dataset(Traverse(ref, pos, seq_bounds=bounds, name="reference"),
                              Traverse(qry, pos + 1.0, name="query"), 4.0, positives=positives, name="d"),
                      tmp_path / "ds")
    mp = build(MapConfig(shortlist="single", rerank="raw+seqmatch", seq_len=5, split="all"), ds, tmp_path / "map")
    econf = EvalConfig(methods=("hvpr-single:raw+seqmatch", "single"), seq_len=5, ks=(1, 5), split="all",
                       extra_radii=(1.0, 12.0))  # 1 m: no query has a frame that near (each is 1.4 m off)
    exact = json.loads(eval_main(econf, ds, tmp_path / "e").path.read_text())["methods"]
    mapped = json.loads(evaluate_main(econf, ds, mp, tmp_path / "m").path.read_text())["methods"]
    assert mapped["hvpr-single:raw+seqmatch"]["positive_not_indexed"] == 30
    for name in econf.methods:
        for key in ("recall@1", "recall@5", "queries", "no_positive"):
            assert mapped[name][key] == pytest.approx(exact[name][key]), (name, key)
        for r in ("1.0", "12.0"):
            assert mapped[name]["radii"][r] == pytest.approx(exact[name]["radii"][r]), (name, r)
