"""``seqnet localize --dataset``: its R@1 is eval's (``--window causal``), and so are eval's notes beside it."""

from __future__ import annotations

import dataclasses
import json
import logging

from seqnet.data.io import save_dataset
from seqnet.localize.config import LocalizeConfig
from seqnet.localize.replay import main as localize_main


def test_localize_says_what_eval_says_about_the_scored_queries(synth_dataset, tmp_path, caplog):
    """No split named test (every query scored) and few scored queries: warned, and kept in the track's JSON."""
    ds = dataclasses.replace(synth_dataset, splits={"train": synth_dataset.splits["train"]})
    path = save_dataset(ds, tmp_path / "ds")
    conf = LocalizeConfig(method="raw+seqmatch", seq_len=3)
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        localize_main(conf, path, tmp_path / "all.csv")
    said = json.loads((tmp_path / "all.json").read_text())["warnings"]
    assert said == [f"no split named test (splits: train); scoring all {len(ds.query)} queries — hint: --split NAME "
                    "(one of train) or a range A:B"], said
    assert any(r.getMessage() == said[0] for r in caplog.records)
    localize_main(dataclasses.replace(conf, split="0:150,10:20"), path, tmp_path / "few.csv")
    record = json.loads((tmp_path / "few.json").read_text())
    n = record["summary"]["queries"]
    assert 0 < n < 10 and record["warnings"][0].startswith(f"only {n} queries scored: one query changes R@1 by 1/{n}")
    localize_main(dataclasses.replace(conf, split="train"), path, tmp_path / "train.csv")
    assert "warnings" not in json.loads((tmp_path / "train.json").read_text())  # nothing to say: no key


def test_the_track_holds_each_frames_truth_and_error(synth_dir, tmp_path):
    """With the dataset's positions: each frame's true position and error, the error within the radius exactly
    where the frame is correct; the JSON holds them, null where unknown."""
    import csv

    localize_main(LocalizeConfig(method="raw+seqmatch", seq_len=3), synth_dir, tmp_path / "t.csv")
    rows = list(csv.DictReader((tmp_path / "t.csv").open()))
    record = json.loads((tmp_path / "t.json").read_text())
    radius = record["config"]["radius"]
    scored = [r for r in rows if r["correct"] != ""]
    assert scored and all(r["error"] != "" and (float(r["error"]) <= radius) == (r["correct"] == "1") for r in scored)
    assert [r["error"] == "" for r in rows] == [e is None for e in record["truth"]["errors"]]
    assert record["truth"]["unit"] == "metres" and all(r["true_x"] != "" for r in rows)


def test_a_replay_with_no_true_match_has_no_r_at_1_and_no_error(synth_dataset, tmp_path):
    """Queries far from every reference of the split: the track is written, with no R@1 in its summary (a missing
    R@1 ended in a KeyError from the few-queries note)."""
    a, b = synth_dataset.splits["train"]["query"]
    far = {"train": {"reference": (a, a + 40), "query": (b - 40, b)}}
    path = save_dataset(dataclasses.replace(synth_dataset, splits=far), tmp_path / "ds")
    localize_main(LocalizeConfig(method="single", split="train"), path, tmp_path / "t.csv")
    summary = json.loads((tmp_path / "t.json").read_text())["summary"]
    assert summary["queries"] == 0 and "recall@1" not in summary and summary["frames"] == 40


def test_hvpr_settings_are_chosen_on_val_as_eval_chooses_them(synth_dir, tmp_path):
    """``localize --dataset`` with an HVPR and no --top-k chooses K on val as ``eval --window causal`` does, says
    so in the track's JSON, and gives eval's R@1; a K given is kept (it used K = 20 whatever eval had chosen)."""
    from seqnet.cli import main as cli_main

    method = "hvpr-delta:raw+seqmatch"
    assert cli_main(["-q", "localize", "--dataset", str(synth_dir), "--method", method, "--seq-len", "3",
                     "--out", str(tmp_path / "t.csv")]) == 0
    record = json.loads((tmp_path / "t.json").read_text())
    chosen = record["selection"]["hvpr"][0]
    assert chosen["method"] == method and "val" in chosen["reason"]
    assert record["config"]["top_k"] == chosen["settings"]["top_k"]
    assert cli_main(["-q", "eval", "--dataset", str(synth_dir), "--method", method, "--seq-len", "3", "--window",
                     "causal", "--out", str(tmp_path / "ev")]) == 0
    ev = json.loads((tmp_path / "ev" / "results.json").read_text())
    assert ev["selection"]["hvpr"][0]["settings"] == chosen["settings"]
    assert abs(ev["methods"][method]["recall@1"] - record["summary"]["recall@1"]) < 1e-9
    assert cli_main(["-q", "localize", "--dataset", str(synth_dir), "--method", method, "--seq-len", "3",
                     "--top-k", "7", "--out", str(tmp_path / "k.csv")]) == 0
    record = json.loads((tmp_path / "k.json").read_text())
    assert record["config"]["top_k"] == 7 and "selection" not in record


def test_hvpr_settings_chosen_on_training_queries_are_warned_as_eval_warns(tmp_path, caplog):
    """``localize --dataset`` choosing K on val queries that the S_1 model trained on says so, in the log and the
    track's JSON, with the few-val-queries warning beside it (the choice's leakage was said by eval only)."""
    from seqnet.cli import main as cli_main
    from seqnet.data.synth import make_synthetic

    ds = make_synthetic(places=200, dim=8)
    data = save_dataset(ds, tmp_path / "ds")
    a, b = ds.ranges("val")["query"]
    assert cli_main(["-q", "--threads", "1", "train", "--dataset", str(data), "--seq-len", "1", "--train-split",
                     f"0:{b}", "--out", str(tmp_path / "run"), "--epochs", "1", "--out-dims", "8", "--n-neg-sample",
                     "50", "--cache-refresh", "40", "--device", "cpu"]) == 0
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        assert cli_main(["localize", "--dataset", str(data), "--model", str(tmp_path / "run" / "best.pt"), "--method",
                         "hvpr-delta:s1+seqmatch", "--seq-len", "3", "--out", str(tmp_path / "t.csv")]) == 0
    said = json.loads((tmp_path / "t.json").read_text())["warnings"]
    leak = [w for w in said if w.startswith("HVPR settings of hvpr-delta:s1+seqmatch chosen on the val split")]
    assert len(leak) == 1 and f"({a}:{b}, {b - a} queries), of which {b - a} are training queries of the S_1" in leak[0]
    assert any("the choice is mostly chance" in w for w in said), said
    logged = [r.getMessage() for r in caplog.records]
    assert all(logged.count(w) == 1 for w in said), logged  # each said once


def test_a_frame_whose_place_has_no_window_in_the_map_is_a_wrong_answer():
    """localize --map scored against positions (a bag's topic, a video's track): a query frame whose correct map
    frames all lie where no window fits is counted, as a wrong answer, as the evaluation counts it."""
    import numpy as np

    from seqnet.localize.replay import frame_truth

    frames = np.c_[10.0 * np.arange(10), np.zeros(10)]  # the map's frames; items: 2..7 (centred L = 5)
    items = np.arange(2, 8)
    q_pos = np.array([[0.5, 0.0], [40.5, 0.0], [500.0, 0.0]])  # at frame 0 (no window), at frame 4, nowhere
    best = np.array([0, 2, 1])  # items 2, 4, 3 answered
    correct, has = frame_truth(q_pos, frames[items], 4.0, best)
    assert has.tolist() == [False, True, False] and correct.tolist() == [False, True, False]
    correct, has = frame_truth(q_pos, frames[items], 4.0, best, frames=frames)
    assert has.tolist() == [True, True, False] and correct.tolist() == [False, True, False]
