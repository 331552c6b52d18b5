"""A run directory whose files are hostile: crafted ``last.pt``, ``config.json`` or ``joint.json``, links planted
where the run's files belong, a user's own files. Every case is one line (exit 2), nothing is written through
a link, nothing seqnet did not write is deleted."""

from __future__ import annotations

import json
import logging
import shutil

import pytest
import torch

import seqnet.train.run as run_module
from seqnet.cli import main as cli_main
from seqnet.data.io import save_dataset
from seqnet.data.synth import make_synthetic
from seqnet.sequence.checkpoints import read_checkpoint

ARGS = ["--epochs", "1", "--seq-len", "3", "--w", "2", "--out-dims", "8", "--optimizer", "adam", "--lr", "1e-2",
        "--n-neg-sample", "50", "--cache-refresh", "40", "--device", "cpu"]


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A dataset and a one-epoch run of it."""
    root = tmp_path_factory.mktemp("hostile")
    data = save_dataset(make_synthetic(places=200, dim=8), root / "ds")
    assert cli_main(["-q", "--threads", "1", "train", "--dataset", str(data), "--out", str(root / "run"), *ARGS]) == 0
    return root


def _cli(capsys, argv):
    capsys.readouterr()
    rc = cli_main(["--threads", "1", *argv])
    return rc, capsys.readouterr().err.strip().splitlines()


def _one_line(capsys, argv, needle, code=2):
    rc, err = _cli(capsys, argv)
    assert rc == code and len(err) == 1 and needle in err[0], (rc, err)
    return err[0]


def _edit(payload, what):
    st = payload["train_state"]
    if what == "huge out_dims":
        payload["model"] = {**payload["model"], "out_dims": 2**40}
    elif what == "newer format":
        payload["format"] = "seqnet-checkpoint/9"
    elif what == "negative index":
        st["neg_cache"][0, 0] = 10**6
    elif what == "float cache":
        st["neg_cache"] = st["neg_cache"].double()
    elif what == "optimiser buffer":
        key = next(iter(st["optimizer"]["state"]))
        st["optimizer"]["state"][key]["exp_avg"] = torch.zeros(3)
    elif what == "optimiser setting":
        st["optimizer"]["param_groups"][0]["lr"] = "fast"
    elif what == "scheduler":
        st["scheduler"]["optimizer"] = 5
    elif what == "generator":
        st["rng"]["generator"] = torch.zeros(3, dtype=torch.uint8)
    elif what == "config":
        payload["config"] = {**payload["config"], "seq_len": 10**30}
    elif what == "epoch":
        payload["epoch"] = -3
    elif what == "dataset path":
        payload["dataset_path"] = 5
    elif what == "history":
        st["history"] = "long"
    elif what == "nan weights":
        payload["state_dict"]["conv.bias"][0] = float("nan")
    return payload


LAST_PT = [("huge out_dims", "model out_dims must be an integer"), ("newer format", "written by a newer seqnet"),
           ("negative index", "indices outside the"), ("float cache", "not an int64 tensor"),
           ("optimiser buffer", "optimiser buffer 'exp_avg'"), ("optimiser setting", "optimiser setting 'lr'"),
           ("scheduler", "unknown scheduler state 'optimizer'"), ("generator", "generator state"),
           ("config", "seq_len must be an integer"), ("epoch", "epoch must be an integer"),
           ("dataset path", "dataset_path must be a path"), ("history", "history must be a list"),
           ("nan weights", "NaN or inf")]


@pytest.mark.parametrize(("what", "needle"), LAST_PT, ids=[w for w, _ in LAST_PT])
def test_a_crafted_last_pt_is_one_line_exit_2(base, tmp_path, capsys, what, needle):
    run = tmp_path / "run"
    shutil.copytree(base / "run", run)
    torch.save(_edit(torch.load(run / "last.pt", weights_only=False), what), run / "last.pt")
    before = (run / "last.pt").read_bytes()
    line = _one_line(capsys, ["train", "--dataset", str(base / "ds"), "--resume", str(run), "--epochs", "2"], needle)
    assert "last.pt" in line or "checkpoint" in line
    assert (run / "last.pt").read_bytes() == before


@pytest.mark.parametrize(("content", "needle"), [
    (b"\x00garbage" * 100, "not a torch file in the zip format"),
    (None, "legacy format is not read"),  # torch's pre-1.6 format
])
def test_a_last_pt_that_is_garbage_or_legacy_is_one_line(base, tmp_path, capsys, content, needle):
    run = tmp_path / "run"
    shutil.copytree(base / "run", run)
    if content is None:
        torch.save(torch.load(run / "last.pt", weights_only=False), run / "last.pt",
                   _use_new_zipfile_serialization=False)
    else:
        (run / "last.pt").write_bytes(content)
    _one_line(capsys, ["train", "--resume", str(run)], needle)


def _dead_run(base, tmp_path, config_text):
    """A run killed in its first epoch (seqnet's manifest, no last.pt) whose config.json is ``config_text``."""
    run = tmp_path / "run"
    shutil.copytree(base / "run", run)
    (run / "last.pt").unlink()
    (run / "config.json").write_text(config_text)
    return run


DEEP = "[" * 100_000 + "]" * 100_000
CONFIGS = [("{not json", "not valid JSON"), ('{"seq_len": NaN}', "not valid JSON"),
           ('{"seq_len": ' + "9" * 5000 + "}", "not valid JSON"), ('{"seq_len": 1e999}', "seq_len must be"),
           ('{"seq_len": 100000000000000000000}', "seq_len must be"), ('{"epochs": "many"}', "epochs must be"),
           ('{"lr": -1}', "lr must be"), ('{"seq_len": ' + DEEP + "}", "not valid JSON"),
           ('{"my": "config"}', "unknown TrainConfig key 'my'"), ("[1, 2]", "must hold a JSON object"),
           ('{"dataset_path": ["x"]}', "dataset_path must be a path"),
           ('{"device": "' + "x" * 100 + '"}', "device must be a device name"),
           (" " * (2 << 20), "more than the")]


@pytest.mark.parametrize(("text", "needle"), CONFIGS, ids=range(len(CONFIGS)))
def test_a_crafted_config_json_of_a_dead_run_is_one_line_exit_2(base, tmp_path, capsys, text, needle):
    run = _dead_run(base, tmp_path, text)
    line = _one_line(capsys, ["train", "--resume", str(run)], needle)
    assert "config.json" in line
    assert (run / "config.json").read_text() == text and (run / "best.pt").is_file()  # nothing discarded


def test_a_dead_run_restarts_with_the_config_json_seqnet_wrote(base, tmp_path, capsys):
    run = _dead_run(base, tmp_path, (base / "run" / "config.json").read_text())
    rc, err = _cli(capsys, ["train", "--resume", str(run), "--epochs", "1"])
    assert rc == 0 and any("starting it again from epoch 1" in x and "discarding best.pt" in x for x in err), err
    assert read_checkpoint(run / "last.pt")["dataset_path"] == str((base / "ds").resolve())


JOINTS = [("{not json", "not valid JSON"), ('{"config": {"seqnet": {}}}', "'config' must hold the settings"),
          ('{"config": {"seqnet": {"seq_len": NaN}, "s1": {}}}', "not valid JSON"),
          ('{"config": {"seqnet": {"w": 99999999999}, "s1": {}}}', "w must be"),
          ('{"config": {"seqnet": {}, "s1": {}}, "dataset_path": 7}', "dataset_path must be a path"),
          ('{"config": ' + DEEP + "}", "not valid JSON"), ("[]", "must hold a JSON object")]


@pytest.mark.parametrize(("text", "needle"), JOINTS, ids=range(len(JOINTS)))
def test_a_crafted_joint_json_is_one_line_exit_2(tmp_path, capsys, text, needle):
    (tmp_path / "j").mkdir()
    (tmp_path / "j" / "joint.json").write_text(text)
    line = _one_line(capsys, ["train", "--resume", str(tmp_path / "j")], needle)
    assert "joint.json" in line


def test_links_where_run_files_belong_are_never_followed(base, tmp_path, capsys):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    for name in ("last.pt", "config.json", "best.pt", ".seqnet-manifest.json"):
        run = tmp_path / f"run-{name}"
        shutil.copytree(base / "run", run)
        (run / name).unlink()
        (run / name).symlink_to(victim)
        _one_line(capsys, ["train", "--resume", str(run), "--epochs", "2"], "symbolic link")
        assert (run / name).is_symlink() and victim.read_text() == "precious"
    dead = tmp_path / "dead"  # a dead run (no last.pt) with a link for its config.json: not restarted
    shutil.copytree(base / "run", dead)
    (dead / "last.pt").unlink()
    (dead / "config.json").unlink()
    (dead / "config.json").symlink_to(base / "run" / "config.json")
    _one_line(capsys, ["train", "--resume", str(dead)], "symbolic link")
    _one_line(capsys, ["train", "--dataset", str(base / "ds"), "--out", str(dead), *ARGS], "is not empty")
    assert (dead / "config.json").is_symlink() and (dead / "best.pt").is_file()
    (tmp_path / "j").mkdir()
    (tmp_path / "j" / "joint.json").symlink_to(victim)
    _one_line(capsys, ["train", "--resume", str(tmp_path / "j")], "symbolic link")


def test_a_link_planted_during_the_run_is_replaced_not_written_through(base, tmp_path, capsys, monkeypatch):
    """Atomic writes rename a new file over the name: a link planted there meanwhile is replaced, its target
    untouched."""
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    real = run_module.save_checkpoint

    def save(path, model, **fields):
        for name in ("best.pt", "last.pt", "config.json"):
            (path.parent / name).unlink(missing_ok=True)
            (path.parent / name).symlink_to(victim)
        return real(path, model, **fields)

    monkeypatch.setattr(run_module, "save_checkpoint", save)
    rc, err = _cli(capsys, ["-q", "train", "--dataset", str(base / "ds"), "--out", str(tmp_path / "r"), *ARGS])
    assert rc == 0, err
    assert victim.read_text() == "precious"
    assert not (tmp_path / "r" / "last.pt").is_symlink() and read_checkpoint(tmp_path / "r" / "last.pt")["epoch"] == 1


def test_a_users_files_are_never_deleted(base, tmp_path, capsys):
    """Only what a seqnet run recorded is started again: a user's config.json, events file or notes stay."""
    cases = {"config.json": '{"my": "config"}', "events.out.tfevents.1.host.2.0": "mine",
             ".last.pt.k2j3.tmp": "mine", "notes.txt": "mine"}
    for name, text in cases.items():
        mine = tmp_path / f"mine-{name}"
        mine.mkdir()
        (mine / name).write_text(text)
        line = _one_line(capsys, ["train", "--dataset", str(base / "ds"), "--out", str(mine), *ARGS], "is not empty")
        assert name in line and (mine / name).read_text() == text
        _one_line(capsys, ["train", "--resume", str(mine)], "checkpoint not found")
        assert sorted(p.name for p in mine.iterdir()) == [name]
    forged = tmp_path / "forged"  # a manifest listing the user's file does not make it seqnet's
    shutil.copytree(base / "run", forged)
    (forged / "last.pt").unlink()
    (forged / "thesis.tex").write_text("precious")
    man = json.loads((forged / ".seqnet-manifest.json").read_text())
    (forged / ".seqnet-manifest.json").write_text(json.dumps({**man, "files": [*man["files"], "thesis.tex"]}))
    _one_line(capsys, ["train", "--dataset", str(base / "ds"), "--out", str(forged), *ARGS], "thesis.tex")
    assert (forged / "thesis.tex").read_text() == "precious" and (forged / "best.pt").is_file()


def test_a_config_json_that_disagrees_with_last_pt_is_explained_and_rewritten(base, tmp_path, capsys, caplog):
    run = tmp_path / "run"
    shutil.copytree(base / "run", run)
    cfg = json.loads((run / "config.json").read_text())
    (run / "config.json").write_text(json.dumps({**cfg, "lr": 5.0}))
    caplog.set_level(logging.WARNING, logger="seqnet")
    rc, err = _cli(capsys, ["-q", "train", "--resume", str(run), "--epochs", "2"])
    assert rc == 0, err
    said = [r.getMessage() for r in caplog.records if "disagreed with last.pt" in r.getMessage()]
    assert len(said) == 1 and "lr" in said[0], said
    assert json.loads((run / "config.json").read_text())["lr"] == cfg["lr"]
    _one_line(capsys, ["train", "--resume", str(run), "--lr", "0.5"], "cannot change 'lr' when resuming")
