"""evaluate(): every method against a direct computation, queries left out, and config errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from seqnet.core.errors import ConfigError
from seqnet.core.tensors import l2_normalize
from seqnet.data.traverse import Dataset, Traverse
from seqnet.eval.evaluate import EvalConfig, evaluate
from seqnet.matching.seqmatch import seqmatch
from seqnet.methods.grammar import default_methods, parse_method, valid_methods
from seqnet.metrics.recall import recall_at_k
from seqnet.search.knn import knn
from seqnet.sequence.descriptors import delta, smoothing
from seqnet.sequence.model import SeqNet
from seqnet.sequence.windows import window_indices, window_starts

ALL = ["single", "smoothing", "delta", "raw+seqmatch", "delta+seqmatch", "hvpr-delta:raw+seqmatch"]


@pytest.fixture(scope="module")
def test_split():
    from seqnet.data.synth import make_synthetic

    return make_synthetic(places=200, dim=16, seed=1).split("test")


@pytest.fixture(scope="module")
def ev(test_split):
    return evaluate(test_split, EvalConfig(methods=tuple(ALL), seq_len=5, device="cpu"))


def stable_order(scores):
    return sorted(range(len(scores)), key=lambda j: (scores[j], j))


def test_results_schema(ev, test_split):
    res = ev.results
    assert list(res["methods"]) == ALL
    n_invalid = int((~window_starts(len(test_split.query), 5, "centred", test_split.query.seq_bounds)[1]).sum())
    for name, entry in res["methods"].items():
        recalls = [entry[f"recall@{k}"] for k in (1, 5, 10, 20, 100)]
        assert all(0.0 <= r <= 1.0 for r in recalls) and recalls == sorted(recalls), name
        view = ev.view(name)  # single: every frame; the sequence methods: the frames with a full window
        assert entry["queries"] + entry["no_positive"] == len(view.q_items)
        assert entry["no_full_window"] == (0 if name == "single" else n_invalid) == len(test_split.query) - len(
            view.q_items)
        assert ("no_full_window_reason" in entry) == (name != "single")
        assert entry["timing_ms"]["total"] >= 0
        assert ev.retrieved[name].shape[0] == len(view.q_items)
    assert res["config"]["seq_len"] == 5 and res["config"]["device"] == "cpu"
    assert res["config"]["dataset"] == test_split.name
    assert ev.retrieved["single"].shape[1] == min(100, len(ev.view("single").r_items))
    assert len(ev.view("single").r_items) == len(test_split.reference) > len(ev.r_items)


def test_single_and_sequence_descriptors_match_direct_knn(ev, test_split):
    q, r = test_split.query, test_split.reference
    fq, fr = (l2_normalize(torch.from_numpy(np.asarray(t.descriptors))) for t in (q, r))
    single = ev.view("single")  # every frame, queried and indexed
    assert single.q_items.tolist() == list(range(len(q))) and single.r_items.tolist() == list(range(len(r)))
    _, ranked = knn(fq[single.q_items], fr[single.r_items], 100, device="cpu")
    np.testing.assert_array_equal(ev.retrieved["single"], ranked)
    for name, fn in (("smoothing", smoothing), ("delta", delta)):
        qs = window_starts(len(q), 5)[0][ev.q_items]
        rs = window_starts(len(r), 5)[0][ev.r_items]
        wq = torch.from_numpy(np.asarray(q.descriptors))[torch.from_numpy(qs[:, None] + np.arange(5))]
        wr = torch.from_numpy(np.asarray(r.descriptors))[torch.from_numpy(rs[:, None] + np.arange(5))]
        _, ranked = knn(fn(wq), fn(wr), 100, device="cpu")
        np.testing.assert_array_equal(ev.retrieved[name], ranked, err_msg=name)


def test_seqmatch_methods_match_direct_map(ev, test_split):
    q, r = test_split.query, test_split.reference
    qs, rs = window_starts(len(q), 5)[0][ev.q_items], window_starts(len(r), 5)[0][ev.r_items]
    raw_q = l2_normalize(torch.from_numpy(np.asarray(q.descriptors)))
    raw_r = l2_normalize(torch.from_numpy(np.asarray(r.descriptors)))
    full = seqmatch(raw_q.double(), raw_r.double(), 5, device="cpu").numpy()
    got = ev.retrieved["raw+seqmatch"]
    for m, a in enumerate(qs):
        row = full[a, rs]
        # same ranking up to float32-vs-float64 near-ties: compare the scores of the retrieved items
        np.testing.assert_allclose(row[got[m]], np.sort(row)[: got.shape[1]], atol=1e-4)
    # delta+seqmatch: SeqMatch over per-frame Delta descriptors (replicate-padded windows)
    dq, dr = (delta(torch.from_numpy(np.asarray(t.descriptors))[torch.from_numpy(window_indices(len(t), 5, "centred",
                                                                                              t.seq_bounds))])
              for t in (q, r))
    full = seqmatch(dq.double(), dr.double(), 5, device="cpu").numpy()
    got = ev.retrieved["delta+seqmatch"]
    for m, a in enumerate(qs):
        row = full[a, rs]
        np.testing.assert_allclose(row[got[m]], np.sort(row)[: got.shape[1]], atol=1e-4)


def test_hvpr_is_delta_shortlist_reranked_by_raw_seqmatch(ev, test_split):
    shortlist = ev.retrieved["delta"]
    hv = ev.retrieved["hvpr-delta:raw+seqmatch"]
    q, r = test_split.query, test_split.reference
    qs, rs = window_starts(len(q), 5)[0][ev.q_items], window_starts(len(r), 5)[0][ev.r_items]
    raw_q = l2_normalize(torch.from_numpy(np.asarray(q.descriptors))).double().numpy()
    raw_r = l2_normalize(torch.from_numpy(np.asarray(r.descriptors))).double().numpy()
    # the first top_k=20 entries are the shortlist re-ranked; the rest keep the shortlist order
    np.testing.assert_array_equal(np.sort(hv[:, :20], axis=1), np.sort(shortlist[:, :20], axis=1))
    np.testing.assert_array_equal(hv[:, 20:], shortlist[:, 20:])
    for m in range(len(qs)):
        s = [sum(np.linalg.norm(raw_q[qs[m] + t] - raw_r[rs[j] + t]) for t in range(5)) for j in hv[m, :20]]
        assert all(a <= b + 1e-4 for a, b in zip(s, s[1:], strict=False)), m


def test_recall_matches_recall_at_k(ev):
    for name, entry in ev.results["methods"].items():
        truth = ev.view(name).truth
        rec = recall_at_k(ev.retrieved[name], truth.q_pos, truth.r_pos, ev.radius)
        for k in (1, 5, 10, 20, 100):
            assert entry[f"recall@{k}"] == rec[f"recall@{k}"]


def test_sequences_beat_single_frames(ev):
    m = ev.results["methods"]
    assert m["raw+seqmatch"]["recall@1"] >= m["single"]["recall@1"]


def test_faiss_backend_and_extra_radii(test_split):
    a = evaluate(test_split, EvalConfig(methods=('single', 'delta'), device='cpu'))
    b = evaluate(test_split, EvalConfig(methods=('single', 'delta'), device='cpu', backend='faiss',
                                        extra_radii=(2.5, 50.0), ks=(1, 3)))
    # the same neighbours up to float32 near-ties: top-1 agrees for (almost) every query
    for name in ("single", "delta"):
        assert (a.retrieved[name][:, 0] == b.retrieved[name][:, 0]).mean() >= 0.95, name
    radii = b.results["methods"]["single"]["radii"]
    assert set(radii) == {"2.5", "50.0"}
    n = b.results["methods"]["single"]["queries"]
    # more positives as it grows
    assert radii["2.5"]["queries"] <= n <= radii["50.0"]["queries"] == len(b.view("single").q_items)
    assert set(b.results["methods"]["single"]) >= {"recall@1", "recall@3"}


def test_with_models(test_split):
    torch.manual_seed(0)
    models = {"seqnet": SeqNet(16, 8, 5, 3), "s1": SeqNet(16, 8, 1, 1)}
    ev = evaluate(test_split, EvalConfig(methods=("seqnet", "s1", "s1+seqmatch", "hvpr"), device="cpu"), models)
    assert ev.results["methods"]["hvpr"]["method"] == {
        "kind": "hvpr", "shortlist": "seqnet", "rerank": "s1+seqmatch", "seq_len": 5, "match_len": 5, "top_k": 20,
        "models": {"s1": models["s1"].config(), "seqnet": models["seqnet"].config()}}
    assert set(ev.results["config"]["models"]) == {"seqnet", "s1"}
    assert all(0 <= e["recall@5"] <= 1 for e in ev.results["methods"].values())
    with pytest.raises(ConfigError, match="expects D=7 descriptors but the dataset has D=16"):
        evaluate(test_split, EvalConfig(methods=('seqnet',)), {"seqnet": SeqNet(7, 8, 5, 3)})
    with pytest.raises(ConfigError, match="needs an S_L model"):
        evaluate(test_split, EvalConfig(methods=('seqnet',)))


def toy(n_q=9, n_r=9, q_bounds=None, dim=3, seed=0):
    rng = np.random.default_rng(seed)
    ref = Traverse(rng.standard_normal((n_r, dim)).astype(np.float32), np.arange(n_r, dtype=float))
    qry = Traverse(rng.standard_normal((n_q, dim)).astype(np.float32), np.arange(n_q, dtype=float), seq_bounds=q_bounds)
    return Dataset(ref, qry, radius=1.0)


def test_seq_len_equal_to_traverse_length():
    ev = evaluate(toy(5, 7), EvalConfig(methods=('single', 'raw+seqmatch', 'smoothing'), seq_len=5, device='cpu'))
    assert ev.q_items.tolist() == [2]  # the only frame with a full centred window
    assert ev.view("single").q_items.tolist() == list(range(5))  # a single frame needs no window
    assert ev.results["methods"]["single"]["no_full_window"] == 0
    assert ev.results["methods"]["smoothing"]["no_full_window"] == 4
    assert ev.results["methods"]["smoothing"]["no_full_window_reason"] == (
        "windows of 5 centred frames (L=5) do not fit within 2 frames of the evaluated range's start or end")
    assert ev.retrieved["raw+seqmatch"].shape == (1, 3)


def test_windows_cut_by_a_split_are_not_blamed_on_sequence_ends():
    """Without sequence bounds the windows lost are cut by the evaluated range's ends (a split's, or the
    traverse's); it said "each sequence end" of a dataset that has none. With bounds it names the sequences."""
    ev = evaluate(toy(12, 12), EvalConfig(methods=("smoothing",), seq_len=5, split="4:10", device="cpu"))
    assert ev.results["methods"]["smoothing"]["no_full_window"] == 4
    assert ev.results["methods"]["smoothing"]["no_full_window_reason"].endswith(
        "within 2 frames of the evaluated range's start or end")
    bounds = np.repeat([[0, 6], [6, 12]], 6, axis=0)
    ev = evaluate(toy(12, 12, bounds), EvalConfig(methods=("smoothing",), seq_len=5, device="cpu"))
    assert ev.results["methods"]["smoothing"]["no_full_window_reason"].endswith(
        "within 2 frames of each sequence's start or end")


def test_seq_len_longer_than_traverse():
    with pytest.raises(ConfigError, match="longer than the query traverse"):
        evaluate(toy(4, 9), EvalConfig(methods=('smoothing',), seq_len=5))
    ev = evaluate(toy(4, 9), EvalConfig(methods=('single',), seq_len=5, device='cpu'))
    assert ev.results["methods"]["single"]["queries"] == 4  # a single frame needs no window


def test_bounds_make_every_window_invalid():
    bounds = np.array([[0, 2], [0, 2], [2, 4], [2, 4], [4, 6], [4, 6]])
    with pytest.raises(ConfigError, match="no query frame has a full window"):
        evaluate(toy(6, 9, bounds), EvalConfig(methods=('smoothing',), seq_len=3))
    ev = evaluate(toy(6, 9, bounds), EvalConfig(methods=('single',), seq_len=3, device='cpu'))
    assert ev.results["methods"]["single"]["queries"] == 6  # a single frame needs no window


def test_seq_len_one():
    ev = evaluate(toy(), EvalConfig(methods=("single", "raw+seqmatch", "smoothing"), seq_len=1, device="cpu"))
    np.testing.assert_array_equal(ev.retrieved["single"], ev.retrieved["raw+seqmatch"])
    with pytest.raises(ConfigError, match="need seq_len >= 2"):
        evaluate(toy(), EvalConfig(methods=('single', 'delta'), seq_len=1))


def test_causal_window():
    ev = evaluate(toy(), EvalConfig(methods=('single', 'smoothing'), seq_len=3, window='causal', device='cpu'))
    assert ev.q_items.tolist() == list(range(2, 9))
    assert ev.view("single").q_items.tolist() == list(range(9))
    assert ev.results["methods"]["smoothing"]["no_full_window_reason"] == (
        "causal windows of 3 frames (L=3) do not fit in the first 2 frames of the evaluated range")


@pytest.mark.parametrize("cfg, pattern", [
    ({"bogus": 1}, "unknown EvalConfig key"),
    ({"methods": []}, "non-empty list"),
    ({"methods": ["nope"]}, "unknown method"),
    ({"seq_len": 0}, "seq_len"),
    ({"radius": -1.0}, "radius"),
    ({"extra_radii": [0]}, "radius"),
    ({"ks": [0, 5]}, "ks must be"),
    ({"ks": []}, "ks must be"),
    ({"top_k": 0}, "top_k"),
    ({"window": "middle"}, "window mode"),
    ({"backend": "annoy"}, "backend"),
    ({"device": "tpu9"}, "device"),
])
def test_config_errors(cfg, pattern):
    with pytest.raises(ConfigError, match=pattern):
        EvalConfig.from_dict(cfg)


def test_no_positive_queries_counted():
    ds = toy()
    far = Traverse(ds.query.descriptors, ds.query.positions + np.array([[0.0]] * 4 + [[100.0]] * 5))
    ev = evaluate(Dataset(ds.reference, far, radius=1.0), EvalConfig(methods=('single',), seq_len=1, device='cpu'))
    entry = ev.results["methods"]["single"]
    assert entry["queries"] == 4 and entry["no_positive"] == 5


def test_all_queries_without_positive_is_an_error():
    ds = toy()
    far = Traverse(ds.query.descriptors, ds.query.positions + 100.0)
    with pytest.raises(ConfigError, match="has a reference within radius 1 frames, so Recall@K is undefined"):
        evaluate(Dataset(ds.reference, far, radius=1.0), EvalConfig(methods=("single",), seq_len=1, device="cpu"))


# ----------------------------------------------------------------------------- methods


def test_parse_method():
    assert parse_method("single").kind == "knn"
    m = parse_method("delta+seqmatch")
    assert (m.kind, m.frames, m.matcher, m.rerank) == ("match", "delta", "seqmatch", "delta+seqmatch")
    m = parse_method("hvpr")  # always the paper's HVPR, whatever models are given
    assert (m.kind, m.shortlist, m.rerank) == ("hvpr", "seqnet", "s1+seqmatch") and m.models() == {"seqnet", "s1"}
    m = parse_method("hvpr-smoothing:delta+seqmatch-rev")
    assert (m.shortlist, m.frames, m.matcher) == ("smoothing", "delta", "seqmatch-rev") and m.models() == set()
    assert parse_method("hvpr-delta").rerank == "s1+seqmatch" and parse_method("hvpr-delta").models() == {"s1"}
    assert parse_method("delta-paper+seqmatch").min_len() == 2
    assert len(valid_methods()) == len(set(valid_methods()))
    for name in valid_methods():
        assert parse_method(name).name == name
    for bad, pattern in (("seqslam", "unknown method"), ("hvpr-nope", "shortlister"),
                         ("hvpr-delta:smoothing", "re-ranker"), ("hvpr-delta:raw+nope", "re-ranker"),
                         ("", "non-empty")):
        with pytest.raises(ConfigError, match=pattern):
            parse_method(bad)


def test_default_methods():
    assert default_methods(set(), 5) == ["single", "smoothing", "delta", "raw+seqmatch", "delta+seqmatch",
                                         "hvpr-delta:raw+seqmatch"]
    both = default_methods({"seqnet", "s1"}, 5)
    assert "hvpr" in both and "hvpr-delta:raw+seqmatch" not in both and "s1+seqmatch" in both
    assert default_methods(set(), 1) == ["single", "smoothing", "raw+seqmatch"]


def test_missing_model_is_an_error_not_a_substitute(test_split):
    with pytest.raises(ConfigError, match="needs an S_1 model"):
        evaluate(test_split, EvalConfig(methods=("hvpr-delta",), device="cpu"))
    with pytest.raises(ConfigError, match="needs an S_L model"):
        evaluate(test_split, EvalConfig(methods=("hvpr",), device="cpu"), {"s1": SeqNet(16, 8, 1, 1)})


def test_match_len_separate_from_seq_len(test_split):
    """L_m for the matchers, L for the descriptors; items need both windows to fit."""
    ev = evaluate(test_split, EvalConfig(methods=("delta", "raw+seqmatch", "hvpr-delta:raw+seqmatch"), seq_len=3,
                                         match_len=7, device="cpu"))
    q = test_split.query
    ok3 = window_starts(len(q), 3, "centred", q.seq_bounds)[1]
    ok7 = window_starts(len(q), 7, "centred", q.seq_bounds)[1]
    np.testing.assert_array_equal(ev.q_items, np.flatnonzero(ok3 & ok7))
    entry = ev.results["methods"]["hvpr-delta:raw+seqmatch"]["method"]
    assert entry["seq_len"] == 3 and entry["match_len"] == 7
    r = test_split.reference
    qs = window_starts(len(q), 7)[0][ev.q_items]
    rs = window_starts(len(r), 7)[0][ev.r_items]
    raw_q = l2_normalize(torch.from_numpy(np.asarray(q.descriptors))).double()
    raw_r = l2_normalize(torch.from_numpy(np.asarray(r.descriptors))).double()
    full = seqmatch(raw_q, raw_r, 7, device="cpu").numpy()
    got = ev.retrieved["raw+seqmatch"]
    for m, a in enumerate(qs):
        row = full[a, rs]
        np.testing.assert_allclose(row[got[m]], np.sort(row)[: got.shape[1]], atol=1e-4)


def test_causal_windows_pin_the_newest_frame_for_anchored_matchers(test_split):
    """With causal windows the item's frame is the window's last: anchored matchers pin it ("end")."""
    from seqnet.matching.graph import graph_topk
    from seqnet.matching.velocity import velocity_topk

    ev = evaluate(test_split, EvalConfig(methods=("raw+vseqmatch", "raw+graph"), seq_len=4, window="causal",
                                         ks=(5,), device="cpu"))
    q, r = test_split.query, test_split.reference
    raw = [l2_normalize(torch.from_numpy(np.asarray(t.descriptors))) for t in (q, r)]
    qs = window_starts(len(q), 4, "causal", q.seq_bounds)[0][ev.q_items]
    rs = window_starts(len(r), 4, "causal", r.seq_bounds)[0][ev.r_items]
    for name, fn in (("raw+vseqmatch", velocity_topk), ("raw+graph", graph_topk)):
        _, items = fn(*raw, 4, 5, qs, rs, anchor="end", device="cpu")
        np.testing.assert_array_equal(ev.retrieved[name], items, err_msg=name)


def test_the_stage_returns_what_it_wrote(synth_dir, tmp_path):
    """``main`` returns the results it wrote (the CLI prints them without reading results.json back)."""
    import json

    from seqnet.core.stage import Written
    from seqnet.eval.evaluate import EvalConfig, main

    got = main(EvalConfig(methods=("single", "raw+seqmatch")), synth_dir, tmp_path / "out")
    assert isinstance(got, Written) and got.path == tmp_path / "out" / "results.json" and got == got.path
    assert json.loads(got.read_text()) == json.loads(json.dumps(got.data))
    assert set(got.data["methods"]) == {"single", "raw+seqmatch"}


def test_hvpr_fused_shortlists_the_documented_top_200_and_says_so():
    from seqnet.methods.grammar import FUSE_WEIGHT, FUSED_TOP_K, parse_method
    from seqnet.pipelines.nordland64 import Nordland64Config
    from seqnet.report.tables import method_label

    fused, plain = parse_method("hvpr-fused"), parse_method("hvpr")
    conf = EvalConfig(top_k=20)
    assert conf.shortlist_size(fused) == FUSED_TOP_K == 200 and conf.shortlist_size(plain) == 20
    assert conf.fuse_weight == FUSE_WEIGHT == 0.25  # the same λ and K on every path: eval, localize, the benchmark
    bench = Nordland64Config().eval_config()
    assert (bench.fuse_weight, bench.shortlist_size(fused)) == (FUSE_WEIGHT, FUSED_TOP_K)
    assert conf.replace(fuse_top_k=50).shortlist_size(fused) == 50
    entry = {"method": {**fused.summary(), "seq_len": 5, "match_len": 5, "top_k": 100, "fuse_weight": 0.5}}
    assert method_label(entry) == "seqnet(L=5) top-100 -> s1+seqmatch(L_m=5)/L_m + 0.5·d(seqnet)"
    entry["method"].pop("fuse_weight")
    assert method_label(entry) == "seqnet(L=5) top-100 -> s1+seqmatch(L_m=5)"


def test_evaluating_training_queries_is_flagged(synth_dir, tmp_path, capsys):
    import json

    from seqnet.cli import main as cli

    assert cli(["-q", "train", "--dataset", str(synth_dir), "--epochs", "1", "--seq-len", "3", "--w", "2",
                "--out", str(tmp_path / "run")]) == 0
    model = str(tmp_path / "run" / "best.pt")
    assert cli(["eval", "--dataset", str(synth_dir), "--model", model, "--split", "all", "--method", "seqnet",
                "--seq-len", "3", "--out", str(tmp_path / "all"), "--report"]) == 0
    leaks = json.loads((tmp_path / "all" / "results.json").read_text())["leakage"]
    assert len(leaks) == 1 and "are training queries of the S_L model" in leaks[0] and "'train'" in leaks[0]
    assert "are training queries" in capsys.readouterr().err
    report = (tmp_path / "all" / "report.html").read_text()  # the shared report says it too, beside the table
    assert 'id="warnings"' in report and "are training queries of the S_L model" in report
    assert cli(["eval", "--dataset", str(synth_dir), "--model", model, "--split", "test", "--method", "seqnet",
                "--seq-len", "3", "--out", str(tmp_path / "test"), "--report"]) == 0
    assert "leakage" not in json.loads((tmp_path / "test" / "results.json").read_text())
    assert "are training queries" not in (tmp_path / "test" / "report.html").read_text()


def test_a_missing_s1_suggests_the_model_free_variant():
    from seqnet.methods.checks import check_methods

    with pytest.raises(ConfigError, match=r"needs an S_1 model .*; or the model-free 'hvpr-single:raw\+seqmatch'"):
        check_methods([parse_method("hvpr-single")], {}, 5)
    with pytest.raises(ConfigError, match=r"S_L model \(--shortlist-model CKPT; models=\{'seqnet': "
                       r"load_model\(CKPT\)\} in Python\); or the model-free .raw\+seqmatch.$"):
        check_methods([parse_method("hvpr")], {}, 5)


def test_a_dataset_built_with_allow_mismatch_remembers_it(synth_dataset, tmp_path):
    from seqnet.core.provenance import ProvenanceError
    from seqnet.core.provenance import make as make_provenance
    from seqnet.data.convert import assemble_dataset
    from seqnet.data.io import load_dataset, save_dataset

    a = make_provenance("describe", {"method": "netvlad", "size": [640, 320]}, dim=16)
    b = make_provenance("describe", {"method": "netvlad", "size": [160, 120]}, dim=16)
    ref = synth_dataset.reference.with_descriptors(synth_dataset.reference.descriptors, a)
    qry = synth_dataset.query.with_descriptors(synth_dataset.query.descriptors, b)
    with pytest.raises(ProvenanceError, match=r"size: \[640, 320\] vs \[160, 120\]"):
        assemble_dataset(ref, qry, "metres", radius=5.0)
    ds = assemble_dataset(ref, qry, "metres", radius=5.0, allow_mismatch=True)
    assert ds.extra["allow_mismatch"] is True
    loaded = load_dataset(save_dataset(ds, tmp_path / "ds"))
    ev = evaluate(loaded, EvalConfig(methods=("single",), seq_len=4))  # no flag needed any more
    assert ev.results["methods"]["single"]["queries"] > 0
    same = assemble_dataset(ref, synth_dataset.query.with_descriptors(synth_dataset.query.descriptors, a), "metres",
                            radius=5.0)
    assert "allow_mismatch" not in same.extra


def test_msls_predictions_file(synth_dir, tmp_path, capsys):
    """MSLS's predictions format: 'query_key ref_key1 ... ref_key20' per line, keys = basenames without extension."""
    from seqnet.cli import main as cli
    from seqnet.data.io import load_dataset

    out = tmp_path / "pred.txt"
    assert cli(["eval", "--dataset", str(synth_dir), "--seq-len", "4", "--method", "single", "--per-query",
                str(out)]) == 0
    text = out.read_text()
    assert text.startswith("# seqnet single: mapillary_sls evaluate.py --task im2im\n")
    lines = [ln.split() for ln in text.splitlines()[1:]]
    ds = load_dataset(synth_dir).split("test")
    ref_keys = {n.rsplit(".", 1)[0] for n in ds.reference.names}
    assert all(len(ln) == 21 and set(ln[1:]) <= ref_keys for ln in lines)
    assert [ln[0] + ".png" for ln in lines] == ds.query.names  # every query image: single needs no window
    assert cli(["eval", "--dataset", str(synth_dir), "--seq-len", "4", "--method", "single,raw+seqmatch",
                "--per-query", str(tmp_path / "two.txt")]) == 2
    assert "holds one method, got 2" in capsys.readouterr().err
    assert cli(["eval", "--dataset", str(synth_dir), "--seq-len", "4", "--method", "raw+seqmatch",
                "--per-query", str(tmp_path / "even.txt")]) == 2  # MSLS's windows are centred, of odd length
    assert "needs centred windows of an odd length" in capsys.readouterr().err


def test_vpr_methods_evaluation_predictions_folder(synth_dir, tmp_path, capsys):
    """VPR-methods-evaluation's saved predictions (visualizations.save_preds): preds/NNN.txt per query with
    'Query path:', the query, 'Predictions paths:', the top predictions, 'Positives paths:', the positives."""
    import re

    from seqnet.cli import main as cli
    from seqnet.data.io import load_dataset

    out = tmp_path / "logs" / "preds"
    argv = ["eval", "--dataset", str(synth_dir), "--seq-len", "4", "--method", "raw+seqmatch", "--per-query", str(out)]
    assert cli(argv) == 0
    whole = load_dataset(synth_dir)
    ds, a = whole.split("test"), whole.ranges("test")["query"][0]
    files = sorted(p.name for p in out.iterdir() if not p.name.startswith("."))
    assert all(re.fullmatch(r"\d{3}\.txt", f) for f in files)
    # numbered by the query's index in the whole query list, as VME: windows of L=4 leave out the split's frames
    # 0, 1 and its last
    assert files[0] == f"{a + 2:03d}.txt" and files[-1] == f"{a + len(ds.query) - 2:03d}.txt"
    assert len(files) == len(ds.query) - 3
    for f in files:
        assert (out / f).read_text().split("\n")[1] == whole.query.names[int(f[:3])]
    text = (out / f"{a + 2:03d}.txt").read_text()
    head, preds, positives = text.split("\n\n")[:3]
    assert head.split("\n")[0] == "Query path:" and head.split("\n")[1] in ds.query.names
    assert preds.split("\n")[0] == "Predictions paths:" and len(preds.split("\n")[1:]) == 5
    assert set(preds.split("\n")[1:]) <= set(ds.reference.names)
    pos = positives.strip("\n").split("\n")
    assert pos[0] == "Positives paths:" and pos[1:] and set(pos[1:]) <= set(ds.reference.names)
    assert text.endswith("\n")
    argv[argv.index("raw+seqmatch")] = "single"  # a single-frame method: every query frame, 000 to the last
    assert cli([*argv, "--overwrite"]) == 0
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == \
        [f"{a + i:03d}.txt" for i in range(len(ds.query))]
    q = ds.query.names.index(head.split("\n")[1])  # the positives: the evaluated references within the radius
    near = [n for n, p in zip(ds.reference.names, ds.reference.positions, strict=True)
            if np.linalg.norm(p - ds.query.positions[q]) <= ds.radius]
    assert set(pos[1:]) <= set(near) and len(near) - len(pos[1:]) <= 3  # L=4: up to 3 frames have no window
    assert cli(argv) == 0  # seqnet's own folder is replaced
    (out / "notes.md").write_text("mine")
    capsys.readouterr()
    assert cli(argv) == 2
    assert "holds 1 file(s) seqnet did not write (first: notes.md)" in capsys.readouterr().err


def test_delta_orig_is_read_as_the_papers_delta_on_every_path(test_split):
    """``delta-paper`` is the paper's Delta (the original code's weighting); its earlier name ``delta-orig`` is
    read as it in every name position, and results always say ``delta-paper``."""
    from seqnet.maps import MapConfig
    from seqnet.methods.grammar import canonical_name
    from seqnet.sequence.descriptors import DESCRIPTOR_ALIASES, SEQUENCE_DESCRIPTORS, delta, delta_paper

    assert SEQUENCE_DESCRIPTORS["delta-paper"].fn is delta_paper and SEQUENCE_DESCRIPTORS["delta"].fn is delta
    assert "delta-orig" not in SEQUENCE_DESCRIPTORS and DESCRIPTOR_ALIASES == {"delta-orig": "delta-paper"}
    for old, new in [("delta-orig", "delta-paper"), ("delta-orig+seqmatch", "delta-paper+seqmatch"),
                     ("hvpr-delta-orig", "hvpr-delta-paper"),
                     ("hvpr-delta-orig:delta-orig+seqmatch-rev", "hvpr-delta-paper:delta-paper+seqmatch-rev"),
                     ("hvpr-fused:delta-orig+seqmatch", "hvpr-fused:delta-paper+seqmatch"), ("delta", "delta"),
                     ("hvpr", "hvpr")]:
        assert canonical_name(old) == new and parse_method(old) == parse_method(new)
    ev = evaluate(test_split, EvalConfig(methods=("delta-orig", "delta", "hvpr-delta-orig:raw+seqmatch"), seq_len=5,
                                         device="cpu"))
    assert list(ev.results["methods"]) == ["delta-paper", "delta", "hvpr-delta-paper:raw+seqmatch"]
    assert ev.results["config"]["methods"] == ["delta-paper", "delta", "hvpr-delta-paper:raw+seqmatch"]
    assert ev.results["methods"]["delta-paper"]["recall@1"] != ev.results["methods"]["delta"]["recall@1"]
    conf = MapConfig.from_dict({"shortlist": "delta-orig", "rerank": "delta-orig+seqmatch"})  # a saved map.json
    assert (conf.shortlist, conf.rerank, conf.method.name) == ("delta-paper", "delta-paper+seqmatch",
                                                               "hvpr-delta-paper:delta-paper+seqmatch")


# ----------------------------------------------------------------------------- single-frame methods: every frame


def test_single_frame_methods_ignore_seq_len():
    """A single frame needs no window: --seq-len 1 and 5 query and index the same frames, with the same results."""
    bounds = np.repeat(np.array([[0, 6], [6, 12]]), 6, axis=0)
    ds = toy(12, 12, bounds)
    one = evaluate(ds, EvalConfig(methods=("single",), seq_len=1, device="cpu"))
    five = evaluate(ds, EvalConfig(methods=("single", "smoothing"), seq_len=5, device="cpu"))
    np.testing.assert_array_equal(one.retrieved["single"], five.retrieved["single"])
    assert one.view("single").q_items.tolist() == five.view("single").q_items.tolist() == list(range(12))
    a, b = one.results["methods"]["single"], five.results["methods"]["single"]
    same = [k for k in a if k not in ("timing_ms", "method")]  # method: the L asked
    assert {k: a[k] for k in same} == {k: b[k] for k in same}
    assert five.q_items.tolist() == [2, 3, 8, 9]  # smoothing: the centred 5-windows inside each 6-frame sequence
    assert five.results["methods"]["smoothing"]["no_full_window"] == 8


def test_mixed_run_gives_single_frame_methods_every_frame(test_split):
    torch.manual_seed(0)
    models = {"s1": SeqNet(16, 8, 1, 1)}
    ev = evaluate(test_split, EvalConfig(methods=("raw+seqmatch", "single", "s1"), seq_len=5, device="cpu"), models)
    assert list(ev.results["methods"]) == ["raw+seqmatch", "single", "s1"]  # the order asked
    n_q, n_r = len(test_split.query), len(test_split.reference)
    for name in ("single", "s1"):
        view = ev.view(name)
        assert view.q_items.tolist() == list(range(n_q)) and view.r_items.tolist() == list(range(n_r))
        assert ev.results["methods"][name]["no_full_window"] == 0
    assert len(ev.q_items) < n_q and ev.view("raw+seqmatch").q_items is ev.q_items
    common = evaluate(test_split, EvalConfig(methods=("single", "raw+seqmatch"), seq_len=5, common_queries=True,
                                             device="cpu"))
    assert list(common.results["methods"]) == ["single", "raw+seqmatch"]  # the order asked, one group
    assert common.view("single").q_items.tolist() == common.q_items.tolist() == ev.q_items.tolist()


def test_single_recall_against_a_naive_loop():
    """Recall@K of single on every frame, against a loop over queries and references."""
    rng = np.random.default_rng(3)
    bounds = np.repeat(np.array([[0, 4], [4, 9]]), [4, 5], axis=0)
    pos = np.arange(9, dtype=float)
    ref = Traverse(rng.standard_normal((9, 4)).astype(np.float32), pos + 0.3, seq_bounds=bounds)
    qry = Traverse(rng.standard_normal((9, 4)).astype(np.float32), pos, seq_bounds=bounds)
    ev = evaluate(Dataset(ref, qry, radius=1.0), EvalConfig(methods=("single", "delta"), seq_len=3, ks=(1, 2, 5),
                                                           device="cpu"))
    nq, nr = (np.asarray(t.descriptors, np.float64) for t in (qry, ref))
    nq, nr = nq / np.linalg.norm(nq, axis=1, keepdims=True), nr / np.linalg.norm(nr, axis=1, keepdims=True)
    for k in (1, 2, 5):
        hits, counted = 0, 0
        for i in range(9):
            if not any(abs(pos[i] - (pos[j] + 0.3)) <= 1.0 for j in range(9)):
                continue
            counted += 1
            order = sorted(range(9), key=lambda j: (np.linalg.norm(nq[i] - nr[j]), j))
            hits += any(abs(pos[i] - (pos[j] + 0.3)) <= 1.0 for j in order[:k])
        assert ev.results["methods"]["single"][f"recall@{k}"] == pytest.approx(hits / counted)
    assert ev.results["methods"]["single"]["queries"] == 9


def test_single_frame_methods_need_no_window_to_fit_the_traverse():
    """A traverse shorter than L: single still scores every frame (it needs no window); a sequence method is
    refused, naming --seq-len."""
    r = np.eye(3, 4, dtype=np.float32)[:2]
    ds = Dataset(Traverse(r, np.arange(2.0)[:, None]), Traverse(r + 0.01, np.arange(2.0)[:, None]), radius=0.5)
    ev = evaluate(ds, EvalConfig(methods=("single",), seq_len=5))
    assert ev.results["methods"]["single"]["queries"] == 2 and ev.results["methods"]["single"]["recall@1"] == 1.0
    with pytest.raises(ConfigError, match="seq_len=5 is longer than the query traverse"):
        evaluate(ds, EvalConfig(methods=("single", "raw+seqmatch"), seq_len=5))


def test_models_the_methods_do_not_use_are_not_loaded(synth_dir, map_models, tmp_path, caplog, monkeypatch):
    """`eval --method raw+seqmatch,s1 --model SL --model S1`: the S_L is mapped for its role and L, never loaded
    (one line names it); the answers are those of a run given only the S_1 and S_L's L."""
    import logging

    from seqnet.cli import main as cli_main
    from seqnet.sequence import checkpoints

    sl, s1 = map_models
    loaded = []
    real = checkpoints.load_model
    monkeypatch.setattr(checkpoints, "load_model", lambda p, **kw: loaded.append(Path(p).name) or real(p, **kw))
    caplog.set_level(logging.INFO, logger="seqnet")
    runs = {"both": ["--model", str(sl), "--model", str(s1)], "flags": ["--shortlist-model", str(sl),
            "--rerank-model", str(s1)], "s1 only": ["--model", str(s1), "--seq-len", "4"]}
    res = {}
    for name, extra in runs.items():
        loaded.clear()
        caplog.clear()
        out = tmp_path / name.replace(" ", "_")
        assert cli_main(["eval", "--dataset", str(synth_dir), "--method", "raw+seqmatch,s1", "--out", str(out),
                         "--device", "cpu", *extra]) == 0
        assert loaded == ["s1.pt"], name
        said = " ".join(r.getMessage() for r in caplog.records)
        assert (f"raw+seqmatch, s1 do not use the model {sl}: not loaded" in said) == (name != "s1 only"), said
        r = json.loads((out / "results.json").read_text())
        assert r["config"]["seq_len"] == 4
        res[name] = {m: v["recall@1"] for m, v in r["methods"].items()}
    assert res["both"] == res["flags"] == res["s1 only"]
    loaded.clear()
    assert cli_main(["eval", "--dataset", str(synth_dir), "--out", str(tmp_path / "all"), "--device", "cpu",
                     *runs["both"]]) == 0  # the default methods: every model they allow is loaded
    assert sorted(loaded) == ["s1.pt", "sl.pt"]


def test_an_hvpr_entry_records_what_its_shortlist_holds(synth_dataset):
    """An HVPR's ``shortlist_recall`` is the share of queries whose K-shortlist holds a correct reference: its own
    R@K (the re-ranking only reorders the first K), the cap of its R@1; other methods have none."""
    conf = EvalConfig(methods=("hvpr-delta:raw+seqmatch", "single"), seq_len=3, top_k=10, ks=(1, 10, 20))
    ev = evaluate(synth_dataset.split("test"), conf)
    entry = ev.results["methods"]["hvpr-delta:raw+seqmatch"]
    assert entry["shortlist_recall"] == {"k": 10, "recall": entry["recall@10"]}
    assert entry["recall@1"] <= entry["shortlist_recall"]["recall"]
    assert "shortlist_recall" not in ev.results["methods"]["single"]
