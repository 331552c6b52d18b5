"""``seqnet eval`` / ``seqnet localize --target-precision``: calibrated on val, applied to test."""

from __future__ import annotations

import csv
import json
import logging

import numpy as np
import pytest

from seqnet.cli import main as cli_main

TARGET = ["--target-precision", "0.9"]


@pytest.fixture(scope="module")
def easy_dir(tmp_path_factory):
    """A synthetic dataset with a val split large and easy enough to calibrate a 0.9 target."""
    from seqnet.data.io import save_dataset
    from seqnet.data.synth import make_synthetic

    ds = make_synthetic(places=1200, dim=32, seed=1, noise=0.3, nuisance=0.2)
    return save_dataset(ds, tmp_path_factory.mktemp("calib") / "ds")


def test_eval_calibrated_matches_per_query(easy_dir, tmp_path, capsys):
    rows = tmp_path / "q.jsonl"
    assert cli_main(["eval", "--dataset", str(easy_dir), "--method", "single,raw+seqmatch", "--seq-len", "3",
                     *TARGET, "--json", str(tmp_path / "r.json"), "--per-query", str(rows), "--device", "cpu"]) == 0
    assert "calibrated on val for precision >= 0.9 (risk 0.05); on test:" in capsys.readouterr().out
    res = json.loads((tmp_path / "r.json").read_text())
    assert cli_main(["eval", "--dataset", str(easy_dir), "--method", "single", "--seq-len", "3", *TARGET,
                     "--per-query", str(tmp_path / "q.csv"), "--device", "cpu"]) == 0
    table = list(csv.DictReader((tmp_path / "q.csv").open()))
    assert sum(r["accepted"] == "1" for r in table) == res["methods"]["single"]["calibrated"]["accepted"]
    assert res["config"]["target_precision"] == 0.9 and res["config"]["calibrate_split"] == "val"
    per = [json.loads(line) for line in rows.read_text().splitlines()]
    for name, entry in res["methods"].items():
        c = entry["calibrated"]
        cal = c["calibration"]
        assert cal["split"] == "val" and cal["threshold"] is not None and cal["lower_bound"] >= 0.9
        mine = [r for r in per if r["method"] == name]
        conf = np.array([r["confidence"] for r in mine])
        ok = np.array([r["correct"][0] for r in mine])
        acc = np.array([r["accepted"] for r in mine])  # the threshold applied as the count was made
        assert np.array_equal(acc[np.abs(conf - cal["threshold"]) > 1e-6], (conf >= cal["threshold"])[
            np.abs(conf - cal["threshold"]) > 1e-6])  # the per-query confidences are rounded to 6 decimals
        assert c["queries"] == len(mine) and c["accepted"] == int(acc.sum()) and c["correct"] == int(ok[acc].sum())
        lo, hi = c["precision_interval"]
        assert lo <= c["precision"] <= hi


def test_eval_calibration_refusals_and_decline(easy_dir, synth_dir, tmp_path, capsys):
    base = ["eval", "--dataset", str(easy_dir), "--method", "raw+seqmatch", "--seq-len", "3", "--device", "cpu"]
    assert cli_main([*base, *TARGET, "--calibrate-split", "test"]) == 2
    assert "overlaps the evaluated split" in capsys.readouterr().err
    assert cli_main([*base, "--risk", "0.1"]) == 2
    assert "go with --target-precision" in capsys.readouterr().err
    assert cli_main([*base, "--target-precision", "1.5"]) == 2
    assert cli_main([*base, *TARGET, "--risk", "0.95"]) == 2  # a confidence level where the risk is meant
    assert "did you mean --risk 0.05?" in capsys.readouterr().err
    assert cli_main([*base, *TARGET, "--calibrate-split", "nope"]) == 2
    # the small synthetic dataset's val split cannot promise 0.99: every query abstains, and why is said
    assert cli_main(["eval", "--dataset", str(synth_dir), "--method", "raw+seqmatch", "--seq-len", "3",
                     "--target-precision", "0.99", "--device", "cpu"]) == 0
    out, err = capsys.readouterr()
    assert "abstains on every query" in out and "abstains" not in err  # said once: in the table


def test_the_api_says_a_method_that_abstains_on_every_query(synth_dir, caplog):
    """Own-data hostile 52 L9: from Python, calibration that abstains on every query was silent (the reason was
    only in results['methods'][m]['calibrated']), where seqnet eval prints it."""
    import logging

    from seqnet import EvalConfig, evaluate, load_dataset

    conf = EvalConfig(methods=("raw+seqmatch",), seq_len=3, target_precision=0.99, device="cpu")
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        ev = evaluate(load_dataset(synth_dir), conf)
    reason = ev.results["methods"]["raw+seqmatch"]["calibrated"]["calibration"]["reason"]
    said = [r.getMessage() for r in caplog.records if "abstains on every query" in r.getMessage()]
    assert said == [f"evaluate(): raw+seqmatch abstains on every query at target precision 0.99 ({reason})"], said


def test_localize_accepted_column(easy_dir, tmp_path, capsys):
    out = tmp_path / "track.csv"
    assert cli_main(["localize", "--dataset", str(easy_dir), "--method", "raw+seqmatch", "--seq-len", "3", *TARGET,
                     "--out", str(out), "--device", "cpu"]) == 0
    assert "calibrated on val for precision >= 0.9" in capsys.readouterr().out
    rows = list(csv.DictReader(out.open()))
    c = json.loads(out.with_suffix(".json").read_text())["summary"]["calibrated"]
    assert c["calibration"]["threshold"] is not None
    accepted = [r for r in rows if r["accepted"] == "1"]
    assert len(accepted) == c["accepted"] and all(r["full_window"] == "1" for r in accepted)
    assert all(float(r["confidence"]) >= c["calibration"]["threshold"] - 1e-6 for r in accepted)
    assert sum(r["correct"] == "1" for r in accepted) == c["correct"]
    assert cli_main(["localize", "--dataset", str(easy_dir), "--out", str(tmp_path / "t2.csv"), "--risk", "0.1"]) == 2
    assert cli_main(["localize", "--dataset", str(easy_dir), "--out", str(tmp_path / "t3.csv"), *TARGET,
                     "--risk", "0.95"]) == 2
    assert "did you mean --risk 0.05?" in capsys.readouterr().err


def test_a_missed_target_is_said(capsys):
    from seqnet.cli.eval_cmd import print_calibration

    def entry(precision: float, met: bool) -> dict:
        return {"calibrated": {"calibration": {"threshold": 0.5, "reason": "", "target": 0.9, "risk": 0.05,
                                               "split": "val"}, "accepted": 90, "queries": 100,
                               "accepted_fraction": 0.9, "precision": precision, "precision_interval": [0.8, 0.9],
                               "recall": 0.8, "target_met": met}}

    res = {"config": {"target_precision": 0.9, "calibrate_split": "val", "risk": 0.05, "split": "test"},
           "methods": {"a": entry(0.95, True), "b": entry(0.85, False)}}
    print_calibration(res)
    out = capsys.readouterr().out.splitlines()
    assert "BELOW" not in out[1] and out[2].endswith("— BELOW the target 0.9") and "measured below" in out[3]
    assert "precision 0.850 [0.800, 0.900] (95% interval), recall 0.800" in out[2]  # the interval's level said
    res["methods"].pop("b")
    print_calibration(res)
    assert "below" not in capsys.readouterr().out.lower()
    from seqnet.cli.localize_cmd import print_calibrated  # localize says the same of its frames

    print_calibrated(entry(0.85, False)["calibrated"])
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("calibrated on val for precision >= 0.9 (risk 0.05): confidence >= 0.5 accepts 90 of "
                             "100 frames") and out[0].endswith("(95% interval), recall 0.800 — BELOW the target 0.9")
    assert "measured below" in out[1]
    print_calibrated(entry(0.95, True)["calibrated"])
    assert "below" not in capsys.readouterr().out.lower()


def test_calibrating_on_training_queries_is_warned(tmp_path, caplog):
    """A threshold calibrated on the queries a model was trained on is optimistic: said, as evaluating on them is."""
    from seqnet.data.io import save_dataset
    from seqnet.data.synth import make_synthetic
    from seqnet.train import TrainConfig, train

    ds = make_synthetic(places=400, dim=16, seed=3, noise=0.3)
    path = save_dataset(ds, tmp_path / "ds")
    train(ds, TrainConfig(seq_len=1, w=1, epochs=1, out_dims=8, device="cpu", n_neg_sample=30,
                                batch_size=32), tmp_path / "run", dataset_path=path)
    caplog.set_level(logging.WARNING, logger="seqnet")
    assert cli_main(["eval", "--dataset", str(path), "--method", "s1", "--model", str(tmp_path / "run" / "best.pt"),
                     "--target-precision", "0.5", "--calibrate-split", "train", "--device", "cpu"]) == 0
    said = " ".join(r.getMessage() for r in caplog.records)
    assert "calibration queries ('train'" in said and "--calibrate-split val" in said


def test_the_report_shows_the_calibration(easy_dir, tmp_path):
    out = tmp_path / "rep"
    assert cli_main(["eval", "--dataset", str(easy_dir), "--method", "single,raw+seqmatch", "--seq-len", "3",
                     *TARGET, "--report", "--out", str(out), "--device", "cpu"]) == 0
    page = (out / "report.html").read_text()
    assert 'id="calibrated"' in page and "Calibrated confidence" in page
    res = json.loads((out / "results.json").read_text())
    for name, entry in res["methods"].items():
        c = entry["calibrated"]
        assert f"<td>{name}</td><td>{c['calibration']['threshold']:.4g}</td>" in page
        assert f"{c['accepted']} of {c['queries']}" in page


def test_the_report_says_a_missed_target():
    from seqnet.report.notes import calibration_section

    c = {"calibration": {"threshold": 0.2}, "accepted": 9, "queries": 10, "precision": 0.7,
         "precision_interval": [0.4, 0.9], "recall": 0.7, "target_met": False}
    declined = {"calibration": {"threshold": None, "reason": "too few queries"}}
    res = {"config": {"target_precision": 0.9, "calibrate_split": "val", "risk": 0.05},
           "methods": {"a<b": {"calibrated": c}, "d": {"calibrated": declined}}}
    body = calibration_section(res)[0].body
    assert "<td>NO</td>" in body and "Below the target: a&lt;b." in body and "too few queries" in body
    assert "[0.400,\u00a00.900]" in body and "<td>declined</td>" in body  # the interval never wraps
    assert "<li>d: too few queries</li>" in body  # the reason under the table, not in a column
    assert calibration_section({"config": {}, "methods": {}}) == []


def test_a_calibration_split_too_short_for_the_windows_says_so(tmp_path, capsys):
    from seqnet.data.io import save_dataset
    from seqnet.data.synth import make_synthetic

    ds = make_synthetic(places=120, dim=16, seed=1, noise=0.3)
    n, r = len(ds.query), len(ds.reference)
    ds.splits = {"val": {"reference": (0, r), "query": (0, 3)}, "test": {"reference": (0, r), "query": (10, n)}}
    path = save_dataset(ds, tmp_path / "ds")
    assert cli_main(["eval", "--dataset", str(path), "--method", "raw+seqmatch", "--seq-len", "5", *TARGET,
                     "--device", "cpu"]) == 2
    err = capsys.readouterr().err
    assert "calibrating on 'val' (queries 0:3, 3 frames): seq_len=5 is longer than the query traverse" in err
    assert "the calibration split is the short one: give --calibrate-split A:B, longer than 3 frames" in err


def test_sequence_confidence_is_what_eval_reports_and_calibrates_on(easy_dir, tmp_path, capsys):
    from seqnet.data.io import load_dataset
    from seqnet.eval.calibrated import top1
    from seqnet.eval.evaluate import EvalConfig, evaluate
    from seqnet.metrics.consistency import QueryOrder, sequence_confidence

    ds = load_dataset(easy_dir).split("test")
    conf = EvalConfig(methods=("single", "raw+seqmatch"), seq_len=3, device="cpu")
    plain, seq = evaluate(ds, conf), evaluate(ds, conf.replace(confidence="sequence"))
    for name in ("single", "raw+seqmatch"):
        view = plain.view(name)
        np.testing.assert_array_equal(seq.retrieved[name], plain.retrieved[name])  # the answers are the same
        bounds = ds.query.seq_bounds
        order = QueryOrder(view.q_items, view.r_items, 3, q_seq=None if bounds is None else bounds[view.q_items, 0])
        want = sequence_confidence(plain.confidence[name], plain.retrieved[name][:, 0], order)
        np.testing.assert_allclose(seq.confidence[name], want)
        np.testing.assert_array_equal(top1(seq, name)[0], seq.confidence[name])  # what calibration thresholds
        assert seq.results["methods"][name]["auc"] >= plain.results["methods"][name]["auc"] - 0.02
    out = tmp_path / "r.json"
    assert cli_main(["eval", "--dataset", str(easy_dir), "--method", "raw+seqmatch", "--seq-len", "3", *TARGET,
                     "--confidence", "sequence", "--json", str(out), "--per-query", str(tmp_path / "q.csv"),
                     "--out", str(tmp_path / "o"), "--report", "--device", "cpu"]) == 0
    page = (tmp_path / "o" / "report.html").read_text()
    assert "Confidence thresholds (sequence confidence) calibrated on val" in page
    assert "seqnet.metrics.consistency" in page and "(seqnet.metrics.precision_recall)" not in page
    assert "for precision >= 0.9 (risk 0.05, sequence confidence); on test:" in capsys.readouterr().out
    res = json.loads(out.read_text())
    assert res["config"]["confidence"] == "sequence"
    rows = list(csv.DictReader((tmp_path / "q.csv").open()))
    np.testing.assert_allclose([float(r["confidence"]) for r in rows], seq.confidence["raw+seqmatch"], atol=1e-6)
    assert cli_main(["eval", "--dataset", str(easy_dir), "--confidence", "votes"]) == 2
    assert "invalid choice" in capsys.readouterr().err
    with pytest.raises(Exception, match="confidence"):
        EvalConfig(confidence="votes")


def test_sequence_confidence_from_a_matrix_and_a_map(synth_dir, tmp_path):
    """The same answers give the same sequence confidence whether they come from descriptors, a distance matrix
    (``--distances``) or a prebuilt map (``--index``)."""
    from seqnet.data.io import load_dataset

    ds = load_dataset(synth_dir)
    q, r = np.asarray(ds.query.descriptors, np.float64), np.asarray(ds.reference.descriptors, np.float64)
    np.save(tmp_path / "d.npy", np.sqrt(((q[:, None] - r[None]) ** 2).sum(-1)).astype(np.float32))
    base = ["-q", "eval", "--dataset", str(synth_dir), "--method", "raw+seqmatch", "--seq-len", "3",
            "--confidence", "sequence", "--device", "cpu"]
    got = {}
    for name, extra in (("descriptors", []), ("matrix", ["--distances", str(tmp_path / "d.npy")])):
        assert cli_main([*base, *extra, "--per-query", str(tmp_path / f"{name}.csv")]) == 0
        got[name] = [(r["reference_indices"].split(";")[0], float(r["confidence"]))
                     for r in csv.DictReader((tmp_path / f"{name}.csv").open())]
    assert [a for a, _ in got["matrix"]] == [a for a, _ in got["descriptors"]]
    np.testing.assert_allclose([c for _, c in got["matrix"]], [c for _, c in got["descriptors"]], atol=2e-6)
    assert cli_main(["-q", "index", "build", "--dataset", str(synth_dir), "--shortlist", "delta", "--rerank",
                     "raw+seqmatch", "--seq-len", "3", "--out", str(tmp_path / "map"), "--device", "cpu"]) == 0
    assert cli_main(["-q", "eval", "--dataset", str(synth_dir), "--index", str(tmp_path / "map"), "--confidence",
                     "sequence", "--json", str(tmp_path / "m.json"), "--device", "cpu"]) == 0
    res = json.loads((tmp_path / "m.json").read_text())
    assert res["config"]["confidence"] == "sequence" and all(0 <= e["auc"] <= 1 for e in res["methods"].values())


def test_one_retrieved_reference_gives_no_confidence(synth_dir, tmp_path, capsys):
    """With --ks 1 a k-NN top-1 has no other place to be compared with: no PR summary (not a confidence of 1 for
    every query), a warning, and --target-precision refused."""
    out = tmp_path / "r.json"
    assert cli_main(["eval", "--dataset", str(synth_dir), "--method", "single,raw+seqmatch,hvpr-delta:raw+seqmatch",
                     "--seq-len", "3", "--ks", "1", "--json", str(out), "--out", str(tmp_path / "o"), "--report",
                     "--device", "cpu"]) == 0
    assert "retrieved one reference per query" in capsys.readouterr().err
    res = json.loads(out.read_text())
    for name in ("single", "raw+seqmatch"):
        e = res["methods"][name]
        assert e["auc"] is None and e["recall@100p"] is None and e["pr_curve"]["recall"] == []
        assert set(e["confidence_for_precision"].values()) == {None}
    assert res["methods"]["hvpr-delta:raw+seqmatch"]["auc"] is not None  # its shortlist is retrieved: K ≥ 2
    assert any("one reference per query" in w for w in res["warnings"])
    assert cli_main(["eval", "--dataset", str(synth_dir), "--method", "single", "--ks", "1", "--target-precision",
                     "0.9", "--device", "cpu"]) == 2
    assert "needs a K of 2 or more" in capsys.readouterr().err


@pytest.mark.parametrize("extra", [[], ["--window", "causal"], ["--seq-len", "1"]])
def test_sequence_confidence_of_model_free_single_frame_methods(synth_dir, tmp_path, extra):
    """The numpy path (single-frame, model-free methods) has the query's sequence bounds too."""
    out = tmp_path / "r.json"
    assert cli_main(["eval", "--dataset", str(synth_dir), "--method", "single", "--confidence", "sequence", *extra,
                     "--json", str(out), "--device", "cpu"]) == 0
    assert json.loads(out.read_text())["methods"]["single"]["auc"] is not None


def test_calibration_on_the_test_split_is_warned():
    """A threshold fitted on the test queries makes every test figure with it optimistic: said for the test split,
    its other spelling and a range inside it, each hint apart from test and the evaluated split; silent otherwise."""
    from seqnet.data.synth import make_synthetic
    from seqnet.eval.calibrated import calibration_on_test

    ds = make_synthetic(places=200, dim=8, seed=1)  # train 0:113, val 113:148, test 148:191 (queries)
    line = calibration_on_test(ds, "test", "val")
    assert line.startswith("--calibrate-split test: calibrating the threshold on the test split makes every test "
                           "figure with it optimistic (hint: --calibrate-split A:B, a range apart from 148:191 and "
                           "113:148)")
    assert calibration_on_test(ds, "test", "0:100").endswith("(hint: --calibrate-split val)")
    inside = calibration_on_test(ds, "160:200", "val")
    assert inside.startswith("--calibrate-split 160:200 holds 31 of the 43 queries of the test split 'test' (148:191)")
    assert calibration_on_test(ds, "val", "test") is None and calibration_on_test(ds, "0:148", "test") is None


def test_eval_and_localize_warn_for_calibrate_split_test(easy_dir, tmp_path, caplog):
    caplog.set_level(logging.WARNING, logger="seqnet")
    base = ["--dataset", str(easy_dir), "--method", "raw+seqmatch", "--seq-len", "3", "--split", "val", *TARGET,
            "--device", "cpu"]

    def said() -> str:
        out = " ".join(r.getMessage() for r in caplog.records)
        caplog.clear()
        return out

    assert cli_main(["eval", *base, "--calibrate-split", "test", "--json", str(tmp_path / "r.json")]) == 0
    line = "--calibrate-split test: calibrating the threshold on the test split makes every test figure"
    assert line in said()
    assert any(line in w for w in json.loads((tmp_path / "r.json").read_text())["warnings"])
    assert cli_main(["localize", *base, "--calibrate-split", "test", "--out", str(tmp_path / "t.csv")]) == 0
    assert line in said()
    assert cli_main(["localize", *base[:6], *TARGET, "--device", "cpu", "--out", str(tmp_path / "t2.csv")]) == 0
    assert "--calibrate-split" not in said()  # calibrated on val, evaluated on test: silent


def test_below_target_on_training_queries_names_that_cause(tmp_path):
    """--calibrate-split train (the models' training queries) was warned, but a precision below the target was then
    blamed on 'a harder stretch of the route': the results record the calibration on training queries and the
    note and the report name it first."""
    from seqnet.cli.common import missed_target_note
    from seqnet.data.io import load_dataset, save_dataset
    from seqnet.data.synth import make_synthetic
    from seqnet.eval.config import EvalConfig as Conf
    from seqnet.eval.evaluate import evaluate
    from seqnet.report.notes import calibration_section
    from seqnet.sequence.checkpoints import load_model
    from seqnet.train.config import TrainConfig
    from seqnet.train.loop import main

    data = save_dataset(make_synthetic(places=200, dim=8), tmp_path / "ds")
    conf = TrainConfig(optimizer="adam", lr=1e-2, batch_size=16, cache_refresh=40, n_neg_sample=50, seq_len=1, w=1,
                       out_dims=8, device="cpu", epochs=1)
    model = {"s1": load_model(main(conf, data, tmp_path / "run") / "best.pt")}
    ds = load_dataset(data)
    on_train = evaluate(ds, Conf(methods=("s1",), seq_len=1, device="cpu", split="test", target_precision=0.3,
                                 calibrate_split="train", risk=0.2), model).results
    assert on_train["config"]["calibrated_on_training_queries"] is True
    on_val = evaluate(ds, Conf(methods=("s1",), seq_len=1, device="cpu", split="test", target_precision=0.9,
                               calibrate_split="val", risk=0.1), model).results
    assert on_val["config"].get("calibrated_on_training_queries") is not True
    assert missed_target_note("train", True).startswith("  (measured below the target: train holds queries the "
                                                        "models were trained on (warned above)")
    assert "harder stretch" in missed_target_note("val")
    entry = on_train["methods"]["s1"]["calibrated"]  # as if a threshold was found and measured below the target
    entry["calibration"]["threshold"] = 0.5
    entry.update(target_met=False, accepted=10, queries=56, precision=0.2, precision_interval=[0.1, 0.4], recall=0.1)
    (section,) = calibration_section(on_train)
    assert "holds queries the models were trained on" in section.body and "harder stretch" not in section.body


def test_a_missing_val_split_gets_a_free_range_to_calibrate_on():
    """A dataset with train and test splits only: '--target-precision' said 'give --calibrate-split' and nothing
    more, while the only named split left was the models' training one; the queries in no split are offered."""
    import dataclasses

    from seqnet.core.errors import ConfigError
    from seqnet.data.synth import make_synthetic
    from seqnet.eval.calibrated import check_calibration_split

    ds = make_synthetic(places=300, dim=8)
    n = len(ds.query)
    two = dataclasses.replace(ds, splits={"train": {"reference": (0, len(ds.reference)), "query": (0, 200)},
                             "test": {"reference": (0, len(ds.reference)), "query": (240, n)}})
    with pytest.raises(ConfigError, match=r"give --calibrate-split \(calibrate_split= in Python\) \(e\.g\. "
                                          r"--calibrate-split 200:240: 40 queries in no split\)$"):
        check_calibration_split(two, "val", "test")
    train = {"reference": (0, len(ds.reference)), "query": (0, 230)}
    tight = dataclasses.replace(two, splits={**two.splits, "train": train})
    with pytest.raises(ConfigError, match=r"in Python\)$"):  # 10 queries free: too few to offer
        check_calibration_split(tight, "val", "test")
