"""``seqnet localize``: the per-frame track of a dataset's query traverse and its summary."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from seqnet.cli import main as cli_main
from seqnet.localize_stage import TRACK_COLUMNS, LocalizeConfig


def test_track_equals_causal_eval(synth_dir, tmp_path, capsys):
    out = tmp_path / "t" / "track.csv"
    assert cli_main(["localize", "--dataset", str(synth_dir), "--method", "raw+seqmatch", "--seq-len", "3",
                     "--out", str(out), "--device", "cpu"]) == 0
    printed = capsys.readouterr().out
    assert "R@1" in printed and "latency per frame" in printed
    rows = list(csv.DictReader(out.open()))
    assert tuple(rows[0]) == TRACK_COLUMNS
    record = json.loads(out.with_suffix(".json").read_text())
    assert record["kind"] == "seqnet-localize/1" and record["config"]["split"] == "test"
    assert len(rows) == record["summary"]["frames"] and rows[0]["estimate"] == "-1" and rows[0]["correct"] == ""
    assert {r["correct"] for r in rows[2:]} <= {"0", "1"} and rows[5]["estimate_name"]
    assert cli_main(["eval", "--dataset", str(synth_dir), "--method", "raw+seqmatch", "--seq-len", "3",
                     "--window", "causal", "--json", str(tmp_path / "ev.json"), "--ks", "1,20", "--device", "cpu"]) == 0
    ev = json.loads((tmp_path / "ev.json").read_text())["methods"]["raw+seqmatch"]
    s = record["summary"]
    assert s["full_window"] == ev["queries"] + ev["no_positive"]
    for key in ("recall@1", "auc", "recall@100p"):
        assert s[key] == pytest.approx(ev[key], abs=1e-9)
    full = [r for r in rows if r["full_window"] == "1"]
    assert np.mean([r["correct"] == "1" for r in full]) == pytest.approx(s["recall@1"] * s["queries"] / len(full))
    assert s["latency_ms"]["median"] > 0


def test_refusals(synth_dir, tmp_path, capsys):
    base = ["localize", "--dataset", str(synth_dir), "--device", "cpu"]
    assert cli_main([*base, "--method", "single", "--out", str(tmp_path / "t.txt")]) == 2
    assert "must be a .csv" in capsys.readouterr().err
    (tmp_path / "mine.json").write_text('{"notes": "mine"}')
    assert cli_main([*base, "--method", "single", "--out", str(tmp_path / "mine.csv")]) == 2
    assert "not written by seqnet localize" in capsys.readouterr().err
    assert json.loads((tmp_path / "mine.json").read_text()) == {"notes": "mine"}
    assert cli_main([*base, "--method", "hvpr", "--out", str(tmp_path / "a.csv")]) == 2
    assert "needs an S_1 model" in capsys.readouterr().err
    assert cli_main([*base, "--method", "raw+grh", "--out", str(tmp_path / "a.csv")]) == 2
    assert "no online form" in capsys.readouterr().err
    assert not (tmp_path / "a.csv").exists()
    with pytest.raises(Exception, match="anchor"):
        LocalizeConfig(anchor="middle")
