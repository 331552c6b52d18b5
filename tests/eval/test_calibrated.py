"""``seqnet eval`` / ``seqnet localize --target-precision``: calibrated on val, applied to test."""

from __future__ import annotations

import csv
import json

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
    assert res["config"]["target_precision"] == 0.9 and res["config"]["calibrate_split"] == "val"
    per = [json.loads(line) for line in rows.read_text().splitlines()]
    for name, entry in res["methods"].items():
        c = entry["calibrated"]
        cal = c["calibration"]
        assert cal["split"] == "val" and cal["threshold"] is not None and cal["lower_bound"] >= 0.9
        mine = [r for r in per if r["method"] == name]
        conf = np.array([r["confidence"] for r in mine])
        ok = np.array([r["correct"][0] for r in mine])
        acc = conf >= cal["threshold"] - 1e-6  # the per-query confidences are rounded to 6 decimals
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
    assert cli_main([*base, *TARGET, "--calibrate-split", "nope"]) == 2
    # the small synthetic dataset's val split cannot promise 0.99: every query abstains, and why is said
    assert cli_main(["eval", "--dataset", str(synth_dir), "--method", "raw+seqmatch", "--seq-len", "3",
                     "--target-precision", "0.99", "--device", "cpu"]) == 0
    assert "abstains on every query" in capsys.readouterr().out


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
