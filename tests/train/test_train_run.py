"""Run reliability: bad splits fail before any file, crash points leave resumable runs, logs and bars."""

from __future__ import annotations

import dataclasses
import logging
import re

import pytest
import torch

import seqnet.train.run as run_module
from seqnet.cli import main as cli_main
from seqnet.core.errors import ConfigError, DatasetError
from seqnet.core.progress import progress_mode
from seqnet.data.synth import make_synthetic
from seqnet.sequence.checkpoints import read_checkpoint
from seqnet.train import TrainConfig, main, train
from seqnet.train.run import resume_config

FAST = TrainConfig(optimizer="adam", lr=1e-2, cache_refresh=40, n_neg_sample=50, seq_len=3, w=2, out_dims=8,
                   device="cpu", epochs=2)


@pytest.fixture(scope="module")
def small():
    return make_synthetic(places=200, dim=8)


def _with_val(ds, query):
    return dataclasses.replace(ds, splits={**ds.splits, "val": {"reference": ds.splits["val"]["reference"],
                                                                "query": query}})


def test_val_split_too_short_for_l_fails_before_any_file(small, tmp_path):
    a, _ = small.splits["val"]["query"]
    with pytest.raises(DatasetError, match="val split: no query frame .* full window of seq_len=5"):
        train(_with_val(small, (a, a + 3)), FAST.replace(seq_len=5), tmp_path / "run")
    assert not (tmp_path / "run").exists()
    far = small.splits["test"]["query"]  # val queries whose places the val references do not cover
    with pytest.raises(DatasetError, match="none of .* val queries"):
        train(_with_val(small, far), FAST, tmp_path / "run")
    assert not (tmp_path / "run").exists()
    run = train(small, FAST.replace(seq_len=5, epochs=1, val_split="none"), tmp_path / "noval")
    assert run.history[0].keys().isdisjoint({"recall@1"}) and run.best_epoch == 1


def _crash_on(monkeypatch, name, epoch):
    real = run_module.save_checkpoint

    def save(path, model, **fields):
        if path.name == name and fields["epoch"] == epoch:
            raise OSError("disk full (simulated)")
        return real(path, model, **fields)

    monkeypatch.setattr(run_module, "save_checkpoint", save)


def test_best_is_written_before_last_and_a_crash_between_resumes_exactly(small, tmp_path, monkeypatch):
    conf = FAST.replace(val_split="none")  # every epoch is the best: best.pt is written every epoch
    straight = train(small, conf, tmp_path / "a")
    _crash_on(monkeypatch, "last.pt", 2)
    with pytest.raises(OSError, match="simulated"):
        train(small, conf, tmp_path / "b")
    monkeypatch.undo()
    last, best = read_checkpoint(tmp_path / "b" / "last.pt"), read_checkpoint(tmp_path / "b" / "best.pt")
    assert last["epoch"] == 1 and best["epoch"] == 2  # best.pt of epoch 2 came first; last.pt is still epoch 1
    assert (tmp_path / "b" / "best.pt").is_file() and last["best_epoch"] <= best["epoch"]
    resumed = train(small, None, tmp_path / "b", resume=True)
    assert resumed.epoch == 2 and [h["loss"] for h in resumed.history] == [h["loss"] for h in straight.history]
    for key, value in read_checkpoint(tmp_path / "a" / "last.pt")["state_dict"].items():
        assert torch.equal(value, read_checkpoint(tmp_path / "b" / "last.pt")["state_dict"][key])


def test_a_crash_writing_best_leaves_last_of_the_previous_epoch(small, tmp_path, monkeypatch):
    _crash_on(monkeypatch, "best.pt", 2)
    with pytest.raises(OSError):
        train(small, FAST.replace(val_split="none"), tmp_path / "r")
    monkeypatch.undo()
    last = read_checkpoint(tmp_path / "r" / "last.pt")
    assert last["epoch"] == last["best_epoch"] == read_checkpoint(tmp_path / "r" / "best.pt")["epoch"] == 1


def test_resume_removes_its_leftover_temp_files(small, tmp_path):
    """Only temporary files carrying seqnet's mark (``.<name>.seqnet-XXXX.tmp``) are a killed write's: a user's
    ``.last.pt.k2j3.tmp`` (no mark) stays."""
    train(small, FAST.replace(epochs=1), tmp_path / "r")
    leftovers = [tmp_path / "r" / n for n in (".last.pt.seqnet-k2j3.tmp", ".best.pt.seqnet-x9.tmp",
                                              ".config.json.seqnet-a1.tmp", "..seqnet-manifest.json.seqnet-b2.tmp")]
    others = [tmp_path / "r" / n for n in ("notes.txt", ".other.pt.x.tmp", ".last.pt.k2j3.tmp", ".best.pt.x9.tmp")]
    for p in leftovers + others:
        p.write_bytes(b"half a checkpoint")
    train(small, resume_config(tmp_path / "r", epochs=2), tmp_path / "r", resume=True)
    assert not any(p.exists() for p in leftovers)
    assert all(p.exists() for p in others)


def test_a_run_stopped_in_its_first_epoch_is_started_again_in_place(small, tmp_path, monkeypatch):
    """Killed before its first last.pt, a run has nothing to resume: the same command starts it again
    (its own config.json and events are replaced); a directory with anything else is still refused."""
    import seqnet.train.loop as loop_module

    def boom(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(loop_module, "train_epoch", boom)
    with pytest.raises(KeyboardInterrupt):
        train(small, FAST, tmp_path / "r")
    assert (tmp_path / "r" / "config.json").is_file() and not (tmp_path / "r" / "last.pt").exists()
    monkeypatch.undo()
    train(small, FAST, tmp_path / "r")
    assert (tmp_path / "r" / "last.pt").is_file()
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "config.json").write_text("{}")
    (tmp_path / "other" / "notes.txt").write_text("mine")
    with pytest.raises(ConfigError, match="is not empty"):
        train(small, FAST, tmp_path / "other")
    assert (tmp_path / "other" / "notes.txt").read_text() == "mine"


def test_main_returns_the_run_directory_and_finds_the_dataset_when_resuming(small, tmp_path):
    from seqnet.data.io import save_dataset

    data = save_dataset(small, tmp_path / "ds")
    out = main(FAST.replace(epochs=1), data, tmp_path / "run")
    assert out == tmp_path / "run" and (out / "best.pt").is_file()
    assert read_checkpoint(out / "last.pt")["dataset_path"] == str(data.resolve())
    again = main(resume_config(out / "last.pt", epochs=2), None, None, resume=out / "last.pt")
    assert again == out and read_checkpoint(out / "last.pt")["epoch"] == 2
    with pytest.raises(ConfigError, match="no run directory"):
        main(FAST, data, None)
    with pytest.raises(ConfigError, match="no dataset"):
        main(FAST, None, tmp_path / "x")


def test_logs_two_info_lines_and_debug_lines_per_epoch_and_at_the_end(small, tmp_path, caplog):
    caplog.set_level(logging.DEBUG, logger="seqnet")
    train(small, FAST, tmp_path / "r")
    mine = [r for r in caplog.records if r.module in ("loop", "run", "mining")]
    info = [r.getMessage() for r in mine if r.levelno == logging.INFO]
    debug = [r.getMessage() for r in mine if r.levelno == logging.DEBUG]
    assert len(info) == 2, info  # the start, the plan (one block: seqnet.train.guide); the CLI prints the end
    assert info[0].startswith("training S_3 (w=2, D 8->8) on ") and "device cpu" in info[0]
    assert info[1].startswith("training plan: S_3") and info[1].count("\n") == 3  # 4 lines, no advice
    assert [m.split(":")[0] for m in debug[:2]] == ["epoch 1/2", "epoch 2/2"]
    assert len(debug) == 3 and debug[2].startswith("trained S_3 for 2 epochs") and "best val R@1" in debug[2]


def test_early_stop_is_in_the_last_line(small, tmp_path, caplog):
    caplog.set_level(logging.DEBUG, logger="seqnet")
    run = train(small, FAST.replace(lr=1e-12, epochs=10, patience=2), tmp_path / "p")
    assert run.epoch == 3
    last = [r.getMessage() for r in caplog.records if r.module == "loop"][-1]
    assert "early stop: no better val R@1 for 2 epochs" in last


def test_one_progress_bar_per_epoch_and_none_for_the_mining_cache(small, tmp_path, capsys):
    with progress_mode(True):
        train(small, FAST.replace(cache_refresh=10), tmp_path / "r")
    err = capsys.readouterr().err
    bars = {m.group(1) for m in re.finditer(r"\r([^\r|]+?):\s+\d+%", err)}
    assert bars == {"epoch 1/2", "epoch 2/2"}, err[:500]  # 12 batches each; nothing for the mining cache
    train(small, FAST.replace(epochs=1), tmp_path / "quiet")  # stderr is not a TTY here: no bar
    assert "\r" not in capsys.readouterr().err


def test_cli_rejects_negative_momentum_weight_decay_and_seed_at_parse_time(tmp_path, capsys):
    for flag in ("--momentum", "--weight-decay", "--seed"):
        assert cli_main(["train", "--dataset", str(tmp_path / "none"), "--out", str(tmp_path / "o"), flag, "-1"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("seqnet train: error: argument") and flag in err[0], err
    assert not (tmp_path / "o").exists()


def test_runs_written_before_train_config_still_resume(small, tmp_path):
    train(small, FAST.replace(epochs=1), tmp_path / "r", dataset_path="data/old")
    path = tmp_path / "r" / "last.pt"
    old = read_checkpoint(path)
    old["config"] = {**old["config"], "dataset_path": old.pop("dataset_path")}  # the dict era kept it there
    old.pop("best_epoch")
    old["train_state"]["rng"] = {**old["train_state"]["rng"], "python": [3, [0] * 3, None], "torch": torch.zeros(1)}
    torch.save(old, path)
    conf = resume_config(tmp_path / "r", epochs=2)
    assert conf.epochs == 2 and conf.seq_len == 3
    run = train(small, conf, tmp_path / "r", resume=True)
    assert run.epoch == 2 and run.dataset_path == "data/old"


def test_a_last_pt_without_its_training_state_is_a_clear_error(small, tmp_path, capsys):
    """A last.pt whose negative cache (or other training state) is missing is refused with one line."""
    import torch

    from seqnet.cli import main as cli_main

    train(small, FAST, tmp_path / "r")
    payload = torch.load(tmp_path / "r" / "last.pt", weights_only=False)
    del payload["train_state"]["neg_cache"]
    torch.save(payload, tmp_path / "r" / "last.pt")
    from seqnet.data.io import save_dataset

    data = save_dataset(small, tmp_path / "ds")
    capsys.readouterr()
    assert cli_main(["train", "--dataset", str(data), "--resume", str(tmp_path / "r"), "--epochs", "3"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "lacks what resuming needs (neg_cache)" in err[0], err


def test_an_epoch_without_an_optimiser_step_warns_nothing_of_torch(small, tmp_path, monkeypatch):
    """No active triplet in the first epoch: the schedule still steps (exact resume), without torch's
    'lr_scheduler.step() before optimizer.step()' UserWarning leaking to the user."""
    import warnings

    import seqnet.train.epoch as epoch_module

    stats = dict.fromkeys(("queries", "skipped", "triplets", "active", "loss"), 0.0)
    monkeypatch.setattr(epoch_module, "train_step", lambda *a, **k: dict(stats))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        run = train(small, FAST.replace(epochs=1, val_split="none"), tmp_path / "r")
    assert run.epoch == 1 and run.scheduler.last_epoch == 1
