"""Training: exact resume, early stopping, S_1, run files, errors and the CLI."""

from __future__ import annotations

import dataclasses
import json
import math

import pytest
import torch

from seqnet.cli import main as cli_main
from seqnet.core.errors import CheckpointError, ConfigError, DatasetError
from seqnet.sequence.checkpoints import load_model, read_checkpoint
from seqnet.train import Run, TrainConfig, train
from seqnet.train.run import resume_config

FAST = TrainConfig(optimizer="adam", lr=1e-2, batch_size=16, cache_refresh=40, n_neg_sample=50, seq_len=3, w=2,
                   out_dims=8, device="cpu", epochs=1)


def _weights(run_dir):
    return read_checkpoint(run_dir / "last.pt")


def test_resume_reproduces_weights_exactly(synth_dataset, tmp_path):
    straight = train(synth_dataset, FAST.replace(epochs=4), tmp_path / "a")
    train(synth_dataset, FAST.replace(epochs=2), tmp_path / "b")
    resumed = train(synth_dataset, resume_config(tmp_path / "b", epochs=4), tmp_path / "b", resume=True)
    a, b = _weights(tmp_path / "a"), _weights(tmp_path / "b")
    assert a["epoch"] == b["epoch"] == 4 and resumed.epoch == 4
    for key in a["state_dict"]:
        assert torch.equal(a["state_dict"][key], b["state_dict"][key]), key
    assert torch.equal(a["train_state"]["neg_cache"], b["train_state"]["neg_cache"])
    assert [h["loss"] for h in straight.history] == [h["loss"] for h in resumed.history]
    # and a different seed does give different weights (the check can fail)
    other = train(synth_dataset, FAST.replace(epochs=1, seed=1), tmp_path / "c")
    assert not torch.equal(other.model.conv.weight.cpu(), _weights(tmp_path / "a")["state_dict"]["conv.weight"])


def test_run_files_and_training_progress(synth_dataset, tmp_path):
    run = train(synth_dataset, FAST.replace(epochs=3), tmp_path / "r", dataset_path="somewhere")
    assert isinstance(run, Run)
    files = {p.name for p in (tmp_path / "r").iterdir()}
    assert {"last.pt", "best.pt", "config.json"} <= files
    assert any(f.startswith("events.out.tfevents") for f in files)
    cfg = json.loads((tmp_path / "r" / "config.json").read_text())
    assert cfg["seq_len"] == 3 and cfg["model"]["w"] == 2 and cfg["neg_radius"] == 20.0
    assert cfg["role"] == "seqnet" and cfg["dataset_path"] == "somewhere"
    stored = read_checkpoint(tmp_path / "r" / "last.pt")
    assert TrainConfig.from_dict(stored["config"]) == FAST.replace(epochs=3).resolve(synth_dataset) == run.conf
    assert stored["dataset_path"] == "somewhere"
    hist = run.history
    assert [h["epoch"] for h in hist] == [1, 2, 3]
    assert all(0.0 <= h["recall@1"] <= 1.0 and h["triplets"] > 0 for h in hist)
    assert hist[-1]["loss"] < hist[0]["loss"]  # it learns something on the training triplets
    best = load_model(tmp_path / "r" / "best.pt")
    assert best.config() == {"in_dims": 16, "out_dims": 8, "seq_len": 3, "w": 2}
    assert read_checkpoint(tmp_path / "r" / "best.pt")["epoch"] == run.best_epoch
    assert run.best_score == max(h["recall@1"] for h in hist)


def test_s1_training_validates_with_s1(synth_dataset, tmp_path):
    run = train(synth_dataset, FAST.replace(seq_len=1, w=1, epochs=1), tmp_path / "s1")
    assert run.model.role == "s1"
    assert not math.isnan(run.history[0]["recall@1"])


def test_early_stopping(synth_dataset, tmp_path):
    run = train(synth_dataset, FAST.replace(lr=1e-12, epochs=10, patience=2), tmp_path / "p")
    assert run.epoch == 3 and run.best_epoch == 1  # nothing changes, so R@1 never improves


def test_resume_rejects_changed_architecture(synth_dataset, tmp_path):
    train(synth_dataset, FAST.replace(epochs=1), tmp_path / "r")
    with pytest.raises(ConfigError, match="cannot change 'seq_len' when resuming"):
        train(synth_dataset, resume_config(tmp_path / "r", seq_len=5, epochs=2), tmp_path / "r", resume=True)
    with pytest.raises(ConfigError, match="cannot change 'seq_len' when resuming"):
        train(synth_dataset, FAST.replace(seq_len=4, epochs=2), tmp_path / "r", resume=True)
    with pytest.raises(ConfigError, match="not empty"):
        train(synth_dataset, FAST, tmp_path / "r")
    with pytest.raises(CheckpointError, match="not found"):
        train(synth_dataset, FAST, tmp_path / "nothing", resume=True)


def test_resume_on_data_of_another_dimension_is_a_checkpoint_error(synth_dataset, tmp_path):
    from seqnet.data.synth import make_synthetic

    train(synth_dataset, FAST.replace(epochs=1), tmp_path / "r")
    other = make_synthetic(places=200, dim=8, seed=1)
    with pytest.raises(CheckpointError, match="does not fit"):
        train(other, resume_config(tmp_path / "r", epochs=2), tmp_path / "r", resume=True)


def _no_positive_dataset(ds):
    n_r, n_q = len(ds.reference), len(ds.query)
    splits = {**ds.splits, "train": {"reference": (0, n_r // 4), "query": (n_q - n_q // 4, n_q)}}
    return dataclasses.replace(ds, splits=splits)


def test_no_positive_for_any_query_is_a_dataset_error(synth_dataset, tmp_path):
    with pytest.raises(DatasetError, match="none of .* training queries"):
        train(_no_positive_dataset(synth_dataset), FAST, tmp_path / "x")
    with pytest.raises(DatasetError, match="no split"):
        train(synth_dataset, FAST.replace(train_split="missing"), tmp_path / "y")
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()


def test_cli_train_then_eval_end_to_end(synth_dir, tmp_path, capsys):
    common = ["--dataset", str(synth_dir), "--epochs", "1", "--optimizer", "adam", "--n-neg-sample", "50",
              "--out-dims", "8", "--device", "cpu"]
    assert cli_main(["train", *common, "--out", str(tmp_path / "sl"), "--seq-len", "3", "--w", "2"]) == 0
    assert cli_main(["train", *common, "--out", str(tmp_path / "s1"), "--seq-len", "1", "--w", "1"]) == 0
    assert cli_main(["train", "--resume", str(tmp_path / "sl"), "--epochs", "2"]) == 0
    assert read_checkpoint(tmp_path / "sl" / "last.pt")["epoch"] == 2
    out = capsys.readouterr().out
    assert "best val R@1" in out
    assert "trained S_3 (w=2, D=16->8) to epoch 2 of 2;" in out.splitlines()[-3]  # the resumed run: its epoch
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


def test_a_val_split_sharing_train_queries_is_warned(synth_dataset, caplog):
    from seqnet.train.loop import prepare

    a, b = synth_dataset.splits["train"]["query"]
    conf, said = FAST.resolve(synth_dataset), "best epoch is chosen on queries it trains on"
    prepare(synth_dataset, conf, torch.device("cpu"))
    assert not any(said in r.getMessage() for r in caplog.records)
    prepare(synth_dataset, conf.replace(val_split=f"{b - 20}:{b}"), torch.device("cpu"))
    [line] = [r.getMessage() for r in caplog.records if said in r.getMessage()]
    assert f"splits train (queries {a}:{b}) and {b - 20}:{b} (queries {b - 20}:{b}) share 20 queries" in line


def test_training_on_copied_queries_is_warned(synth_dataset, caplog):
    """The reference images given as the query: every triplet is trivial and val scores 1.000; said before
    training (dataset building says it too, but a dataset made elsewhere reaches training unsaid)."""
    import dataclasses

    from seqnet.data.traverse import Traverse
    from seqnet.train.loop import prepare

    conf = FAST.resolve(synth_dataset)
    prepare(synth_dataset, conf, torch.device("cpu"))
    assert not any("trivially perfect" in r.getMessage() for r in caplog.records)
    r = synth_dataset.reference
    copy = dataclasses.replace(synth_dataset, query=Traverse(r.descriptors.copy(), r.positions, name="query"),
                               splits={n: {"reference": s["reference"], "query": s["reference"]}
                                       for n, s in synth_dataset.splits.items()})
    prepare(copy, conf, torch.device("cpu"))
    [line] = [r.getMessage() for r in caplog.records if "trivially perfect" in r.getMessage()]
    assert line.startswith("training on the 'train' split: ") and "the query images are the reference images" in line


def test_training_on_a_query_traverse_run_backwards_is_warned(synth_dataset, caplog):
    """The query traverse driven opposite to the reference: eval's route-direction warning, said at train time
    before any epoch (an S_L learns nothing useful from windows reversed on one side); not for S_1."""
    import dataclasses

    from seqnet.data.traverse import Traverse
    from seqnet.train.loop import prepare

    conf, said = FAST.resolve(synth_dataset).replace(train_split="all", val_split="none"), "runs opposite"
    prepare(synth_dataset, conf, torch.device("cpu"))
    assert not any(said in r.getMessage() for r in caplog.records)
    q = synth_dataset.query
    back = dataclasses.replace(synth_dataset, query=Traverse(q.descriptors[::-1].copy(), q.positions[::-1].copy(),
                                                             name="query"), splits={})
    prepare(back, conf, torch.device("cpu"))
    [line] = [r.getMessage() for r in caplog.records if said in r.getMessage()]
    assert line.startswith("training on the 'all' split: the query traverse runs opposite to the reference")
    assert "(correlation -1.00)" in line
    caplog.clear()
    prepare(back, conf.replace(seq_len=1, w=1), torch.device("cpu"))
    assert not any(said in r.getMessage() for r in caplog.records)
