"""Training: config resolution, exact resume, early stopping, S_1, run files, errors and the CLI."""

from __future__ import annotations

import dataclasses
import json
import math

import pytest
import torch

from seqnet.cli import main as cli_main
from seqnet.errors import CheckpointError, ConfigError, DatasetError
from seqnet.train.checkpoints import load_model, model_role, read_checkpoint
from seqnet.train.loop import resolve_train_config, train

FAST = {"optimizer": "adam", "lr": 1e-2, "batch_size": 16, "cache_refresh": 40, "n_neg_sample": 50,
        "seq_len": 3, "w": 2, "out_dims": 8, "device": "cpu"}


def test_config_defaults_come_from_the_paper_and_the_dataset(synth_dataset):
    cfg = resolve_train_config(None, synth_dataset)
    keys = ("margin", "lr", "momentum", "weight_decay", "optimizer", "lr_step", "lr_gamma", "batch_size")
    assert [cfg[k] for k in keys] == [0.3, 1e-4, 0.9, 1e-3, "sgd", 50, 0.5, 16]
    assert (cfg["n_negatives"], cfg["n_neg_sample"]) == (10, 1000)
    assert (cfg["pos_radius"], cfg["neg_radius"]) == (5.0, 20.0)  # dataset.extra
    assert cfg["out_dims"] == synth_dataset.query.dim
    bare = dataclasses.replace(synth_dataset, extra={}, radius=3.0)
    assert resolve_train_config(None, bare)["neg_radius"] == 12.0  # radius and 4 x radius
    assert resolve_train_config({"pos_radius": 2.0}, bare)["neg_radius"] == 8.0


@pytest.mark.parametrize("bad", [{"w": 4, "seq_len": 3}, {"optimizer": "rmsprop"}, {"lr": 0}, {"pos_radius": 30.0},
                                 {"nonsense": 1}, {"batch_size": 0}, {"cache_refresh": -1}])
def test_bad_config_raises_config_error(synth_dataset, bad):
    with pytest.raises(ConfigError):
        resolve_train_config(bad, synth_dataset)


def _weights(run_dir):
    return read_checkpoint(run_dir / "last.pt")


def test_resume_reproduces_weights_exactly(synth_dataset, tmp_path):
    straight = train(synth_dataset, {**FAST, "epochs": 4}, tmp_path / "a")
    train(synth_dataset, {**FAST, "epochs": 2}, tmp_path / "b")
    resumed = train(synth_dataset, {"epochs": 4}, tmp_path / "b", resume=True)
    a, b = _weights(tmp_path / "a"), _weights(tmp_path / "b")
    assert a["epoch"] == b["epoch"] == 4 and resumed.epoch == 4
    for key in a["state_dict"]:
        assert torch.equal(a["state_dict"][key], b["state_dict"][key]), key
    assert torch.equal(a["train_state"]["neg_cache"], b["train_state"]["neg_cache"])
    assert [h["loss"] for h in straight.history] == [h["loss"] for h in resumed.history]
    # and a different seed does give different weights (the check can fail)
    other = train(synth_dataset, {**FAST, "epochs": 1, "seed": 1}, tmp_path / "c")
    assert not torch.equal(other.model.conv.weight.cpu(), _weights(tmp_path / "a")["state_dict"]["conv.weight"])


def test_run_files_and_training_progress(synth_dataset, tmp_path):
    run = train(synth_dataset, {**FAST, "epochs": 3}, tmp_path / "r")
    files = {p.name for p in (tmp_path / "r").iterdir()}
    assert {"last.pt", "best.pt", "config.json"} <= files
    assert any(f.startswith("events.out.tfevents") for f in files)
    cfg = json.loads((tmp_path / "r" / "config.json").read_text())
    assert cfg["seq_len"] == 3 and cfg["model"]["w"] == 2 and cfg["neg_radius"] == 20.0
    hist = run.history
    assert [h["epoch"] for h in hist] == [1, 2, 3]
    assert all(0.0 <= h["recall@1"] <= 1.0 and h["triplets"] > 0 for h in hist)
    assert hist[-1]["loss"] < hist[0]["loss"]  # it learns something on the training triplets
    best = load_model(tmp_path / "r" / "best.pt")
    assert best.config() == {"in_dims": 16, "out_dims": 8, "seq_len": 3, "w": 2}
    assert read_checkpoint(tmp_path / "r" / "best.pt")["epoch"] == run.best_epoch
    assert run.best_score == max(h["recall@1"] for h in hist)


def test_s1_training_validates_with_s1(synth_dataset, tmp_path):
    run = train(synth_dataset, {**FAST, "seq_len": 1, "w": 1, "epochs": 1}, tmp_path / "s1")
    assert model_role(run.model) == "s1"
    assert not math.isnan(run.history[0]["recall@1"])


def test_early_stopping(synth_dataset, tmp_path):
    run = train(synth_dataset, {**FAST, "lr": 1e-12, "epochs": 10, "patience": 2}, tmp_path / "p")
    assert run.epoch == 3 and run.best_epoch == 1  # nothing changes, so R@1 never improves


def test_resume_rejects_changed_architecture(synth_dataset, tmp_path):
    train(synth_dataset, {**FAST, "epochs": 1}, tmp_path / "r")
    with pytest.raises(ConfigError, match="seq_len"):
        train(synth_dataset, {"seq_len": 5, "epochs": 2}, tmp_path / "r", resume=True)
    with pytest.raises(ConfigError, match="not empty"):
        train(synth_dataset, FAST, tmp_path / "r")
    with pytest.raises(CheckpointError, match="not found"):
        train(synth_dataset, FAST, tmp_path / "nothing", resume=True)


def test_resume_on_data_of_another_dimension_is_a_checkpoint_error(synth_dataset, tmp_path):
    from seqnet.data.synth import make_synthetic

    train(synth_dataset, {**FAST, "epochs": 1}, tmp_path / "r")
    other = make_synthetic(places=200, dim=8, seed=1)
    with pytest.raises(CheckpointError, match="does not fit"):
        train(other, {"epochs": 2}, tmp_path / "r", resume=True)


def _no_positive_dataset(ds):
    n_r, n_q = len(ds.reference), len(ds.query)
    splits = {**ds.splits, "train": {"reference": (0, n_r // 4), "query": (n_q - n_q // 4, n_q)}}
    return dataclasses.replace(ds, splits=splits)


def test_no_positive_for_any_query_is_a_dataset_error(synth_dataset, tmp_path):
    with pytest.raises(DatasetError, match="none of .* training queries"):
        train(_no_positive_dataset(synth_dataset), FAST, tmp_path / "x")
    with pytest.raises(DatasetError, match="no split"):
        train(synth_dataset, {**FAST, "train_split": "missing"}, tmp_path / "y")


def test_cli_train_then_eval_end_to_end(synth_dir, tmp_path, capsys):
    common = ["--dataset", str(synth_dir), "--epochs", "1", "--optimizer", "adam", "--n-neg-sample", "50",
              "--out-dims", "8", "--device", "cpu"]
    assert cli_main(["train", *common, "--out", str(tmp_path / "sl"), "--seq-len", "3", "--w", "2"]) == 0
    assert cli_main(["train", *common, "--out", str(tmp_path / "s1"), "--seq-len", "1", "--w", "1"]) == 0
    assert cli_main(["train", "--resume", str(tmp_path / "sl"), "--epochs", "2"]) == 0
    assert read_checkpoint(tmp_path / "sl" / "last.pt")["epoch"] == 2
    out = capsys.readouterr().out
    assert "best val R@1" in out
    args = ["eval", "--dataset", str(synth_dir), "--seq-len", "3",
            "--shortlist-model", str(tmp_path / "sl" / "best.pt"), "--rerank-model", str(tmp_path / "s1" / "best.pt"),
            "--top-k", "5", "--method", "seqnet,s1,s1+seqmatch,hvpr"]
    assert cli_main(args) == 0
    table = capsys.readouterr().out
    for method in ("seqnet", "s1+seqmatch", "hvpr"):
        assert f"\n{method} " in table
    assert cli_main(["eval", "--dataset", str(synth_dir), "--model", str(tmp_path / "sl" / "best.pt"),
                     "--model", str(tmp_path / "s1" / "best.pt")]) == 0


def test_cli_train_bad_inputs_exit_2_with_one_line(synth_dataset, synth_dir, tmp_path, capsys):
    from seqnet.data.io import save_dataset

    bad = save_dataset(_no_positive_dataset(synth_dataset), tmp_path / "bad")
    cases = [["--dataset", str(bad), "--out", str(tmp_path / "o1")],
             ["--dataset", str(synth_dir), "--out", str(tmp_path / "o2"), "--seq-len", "2", "--w", "3"],
             ["--resume", str(tmp_path / "nowhere")]]
    for case in cases:
        assert cli_main(["train", *case]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("seqnet train: error:"), err
