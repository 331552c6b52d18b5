"""Fixed-time re-sampling (data.resample): every N-th frame of the recorded order, everything re-indexed alike."""

from __future__ import annotations

import json

import numpy as np
import pytest

from seqnet.cli import main
from seqnet.core.errors import ConfigError, DatasetError
from seqnet.data.io import load_dataset, save_dataset
from seqnet.data.positives import Positives
from seqnet.data.resample import resample_dataset
from seqnet.data.synth import make_synthetic
from seqnet.data.traverse import Dataset, Traverse
from seqnet.eval.evaluate import EvalConfig, evaluate
from seqnet.metrics.recall import ground_truth


def _dataset(n: int = 40, positives: bool = False) -> Dataset:
    rng = np.random.default_rng(0)
    speed = rng.uniform(0.5, 3.0, n)  # metres between frames: fixed-time frames are not fixed-distance
    pos = np.stack([np.cumsum(speed), np.zeros(n)], axis=1)
    bounds = np.array([[0, 17] if i < 17 else [17, n] for i in range(n)])
    names = [f"img{i:03d}.png" for i in range(n)]
    ref = Traverse(rng.standard_normal((n, 4)).astype(np.float32), pos, names, bounds, "reference")
    qry = Traverse(rng.standard_normal((n, 4)).astype(np.float32), pos + 0.3, list(names), bounds.copy(), "query")
    pos_lists = Positives.from_lists([[i - 1, i, i + 1] if 0 < i < n - 1 else [i] for i in range(n)]) \
        if positives else None
    return Dataset(ref, qry, 2.0, splits={"train": {"reference": (0, 20), "query": (0, 20)},
                                          "test": {"reference": (20, 40), "query": (21, 40)}},
                   name="toy", positives=pos_lists)


def test_every_nth_frame_of_the_query_and_its_fields(tmp_path):
    ds = _dataset()
    out = resample_dataset(ds, 6, "query")
    keep = [0, 6, 12, 18, 24, 30, 36]
    assert out.reference is ds.reference and len(out.query) == 7
    assert out.query.names == [f"img{i:03d}.png" for i in keep]
    np.testing.assert_array_equal(out.query.descriptors, ds.query.descriptors[keep])
    np.testing.assert_array_equal(out.query.positions, ds.query.positions[keep])
    # frames 0, 6, 12 were in sequence 0:17, the others in 17:40 -> new bounds 0:3 and 3:7
    assert out.query.seq_bounds.tolist() == [[0, 3]] * 3 + [[3, 7]] * 4
    assert out.splits == {"train": {"reference": (0, 20), "query": (0, 4)},
                          "test": {"reference": (20, 40), "query": (4, 7)}}  # 0,6,12,18 | 24,30,36
    assert out.extra["resample"] == [{"every": 6, "side": "query"}]
    save_dataset(out, tmp_path / "ds")
    back = load_dataset(tmp_path / "ds")
    assert back.extra["resample"] == [{"every": 6, "side": "query"}] and back.splits == out.splits


def test_ground_truth_stays_right_by_radius_and_by_positives():
    ds = _dataset(positives=True)
    out = resample_dataset(ds, 3, "both")
    kq = kr = np.arange(0, 40, 3)
    every = np.tile(np.arange(len(kr)), (len(kq), 1))  # [M, R]: every reference, for the full match mask
    radius = ground_truth(out.query.positions, out.reference.positions, 2.0).hits(every)
    direct = ground_truth(ds.query.positions[kq], ds.reference.positions[kr], 2.0).hits(every)
    np.testing.assert_array_equal(radius, direct)
    assert radius.any() and not radius.all()
    for i, q in enumerate(kq):  # explicit positives: the kept references among q's, renumbered
        want = [j for j, r in enumerate(kr) if r in ds.positives.of(int(q))]
        assert out.positives.of(i).tolist() == want
    assert out.positives.of(1).tolist() == [1]  # query 3 matches reference 3 (new index 1); 2, 4 dropped


def test_one_is_the_identity_and_bad_values_are_refused():
    ds = _dataset()
    assert resample_dataset(ds, 1, "both") is ds and resample_dataset(ds, None) is ds
    with pytest.raises(ConfigError, match="resample side 'sideways' is not one of query, reference, both"):
        resample_dataset(ds, 2, "sideways")
    with pytest.raises(ConfigError, match="integer >= 1"):
        resample_dataset(ds, 0)
    with pytest.raises(DatasetError, match="split 'test': no query frame of 21:40 is kept"):
        resample_dataset(ds, 41, "query")  # keeps frame 0 only


def test_eval_resamples_the_evaluated_split_and_records_it():
    ds = make_synthetic(places=200, dim=8, seed=0).split("test")
    conf = EvalConfig(methods=("single",), seq_len=1, device="cpu", ks=(1,))
    full = evaluate(ds, conf)
    ev = evaluate(ds, conf.replace(resample_every=6))
    assert ev.results["config"]["resample_every"] == 6 and ev.results["config"]["resample_side"] == "query"
    np.testing.assert_array_equal(ev.q_items, np.arange(len(range(0, len(ds.query), 6))))  # the kept queries
    np.testing.assert_array_equal(ev.q_pos, ds.query.positions[::6])
    assert np.array_equal(full.q_items, np.arange(len(ds.query)))
    # the same queries, ranked against the same reference: identical rows of the full evaluation
    np.testing.assert_array_equal(ev.retrieved["single"], full.retrieved["single"][::6])
    with pytest.raises(ConfigError, match="resample side"):
        EvalConfig(resample_side="left")


def test_per_query_rows_number_frames_as_before_resampling():
    """--per-query's query_index / reference_indices are the dataset's rows before re-sampling (the split's frame
    numbers plus its start), not the re-sampled indices."""
    from seqnet.eval.results import per_query_rows, query_start, reference_start

    ds = make_synthetic(places=120, dim=8, seed=0).split("test")
    conf = EvalConfig(methods=("single", "raw+seqmatch"), seq_len=3, device="cpu", ks=(1, 5))
    ev = evaluate(ds, conf)
    q0, r0 = query_start(ev), reference_start(ev)
    full = {(r["method"], r["query_index"]): r for r in per_query_rows(ev)}
    for side in ("query", "reference", "both"):
        rows = per_query_rows(evaluate(ds, conf.replace(resample_every=3, resample_side=side)))
        assert rows and all((r["query_index"] - q0) % 3 == 0 for r in rows) if side != "reference" else True
        step = 3 if side != "query" else 1
        assert all((j - r0) % step == 0 for r in rows for j in r["reference_indices"] if j >= 0)
        if side == "reference":
            assert {r["query_index"] - q0 for r in rows if r["method"] == "single"} == set(range(len(ds.query)))
        else:  # a kept query frame's name is the full evaluation's row of that frame number
            known = [r for r in rows if (r["method"], r["query_index"]) in full]
            assert all(full[(r["method"], r["query_index"])]["query_name"] == r["query_name"] for r in known)
            assert len({r["query_name"] for r in rows}) == len({r["query_index"] for r in rows})
    single = [r for r in per_query_rows(evaluate(ds, conf.replace(resample_every=3))) if r["method"] == "single"]
    assert [r["reference_indices"] for r in single] == [full[("single", r["query_index"])]["reference_indices"]
                                                        for r in single]


def test_cli_dataset_resample_and_eval_flag(tmp_path, capsys):
    ds = make_synthetic(places=120, dim=8, seed=0)
    save_dataset(ds, tmp_path / "ds")
    assert main(["dataset", "resample", str(tmp_path / "ds"), "--every", "4", "--side", "both",
                 "--out", str(tmp_path / "ft")]) == 0
    ft = load_dataset(tmp_path / "ft")
    assert len(ft.query) == len(range(0, len(ds.query), 4)) and len(ft.reference) == len(range(0, len(ds.reference), 4))
    assert ft.name.endswith("-every4") and main(["dataset", "check", str(tmp_path / "ft")]) == 0
    assert main(["eval", "--dataset", str(tmp_path / "ds"), "--methods", "single", "--seq-len", "1",
                 "--resample-every", "4", "--recall-denominator", "all", "--device", "cpu",
                 "--out", str(tmp_path / "ev")]) == 0
    res = json.loads((tmp_path / "ev" / "results.json").read_text())
    assert res["config"]["resample_every"] == 4 and res["config"]["resample_side"] == "query"
    assert res["config"]["recall_denominator"] == "all"  # --recall-denominator: eval's flag, shown in the table
    out = capsys.readouterr().out
    assert "every 4th query frame" in out and "method (R@K ÷ all)" in out


def test_repeated_frames_keep_their_sequences_bounds_and_out_of_order_is_refused():
    """A variable-speed re-sampling (frames repeated, non-decreasing) through the one re-indexer."""
    from seqnet.data.resample import resample_traverse
    from seqnet.data.traverse import Traverse

    bounds = np.array([[0, 3]] * 3 + [[3, 6]] * 3)
    t = Traverse(np.arange(12, dtype=np.float32).reshape(6, 2), np.arange(6.0), names=list("abcdef"), seq_bounds=bounds)
    keep = np.array([0, 0, 2, 3, 3, 3, 5])
    r = resample_traverse(t, keep)
    naive = [[min(j for j in range(len(keep)) if keep[j] >= bounds[k][0]),
              min([j for j in range(len(keep)) if keep[j] >= bounds[k][1]] or [len(keep)])] for k in keep]
    assert r.seq_bounds.tolist() == naive == [[0, 3]] * 3 + [[3, 7]] * 4
    assert r.names == list("aacdddf") and r.descriptors[:, 0].tolist() == (2 * keep).tolist()
    with pytest.raises(ConfigError, match="recorded order"):
        resample_traverse(t, np.array([2, 1]))
