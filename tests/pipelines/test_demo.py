"""The demo trains S_L and S_1 and shows the learned methods next to the baselines."""

from __future__ import annotations

import json

import pytest
import torch

from seqnet.cli import main as cli_main
from seqnet.core.errors import ConfigError
from seqnet.pipelines.demo import BASELINES, LEARNED, MODEL_FREE_HVPR, DemoConfig, main


@pytest.fixture
def keep_threads():
    n = torch.get_num_threads()
    yield
    assert torch.get_num_threads() == n  # the CLI restores the thread count after the command


def test_cli_demo_trains_and_evaluates_every_method(tmp_path, capsys, keep_threads):
    methods = [*BASELINES, *LEARNED]
    (tmp_path / "notes.txt").write_text("mine")
    assert cli_main(["demo", "--places", "200", "--epochs", "1", "--out", str(tmp_path), "--device", "cpu"]) == 0
    out = capsys.readouterr().out
    for method in methods:
        assert f"\n{method} " in out
    assert "trained on the train split" in out
    saved = json.loads((tmp_path / "results.json").read_text())
    assert list(saved["methods"]) == methods
    assert all(0.0 <= m["recall@1"] <= 1.0 for m in saved["methods"].values())
    cfg = saved["config"]
    assert cfg["models"]["s1"]["seq_len"] == 1 and cfg["models"]["seqnet"]["seq_len"] == 5
    assert set(cfg["train_seconds"]) == {"seqnet", "s1"} and cfg["demo"]["train"]["epochs"] == 1
    for role in ("seqnet", "s1"):
        assert (tmp_path / f"train_{role}" / "best.pt").is_file()
    run = json.loads((tmp_path / "train_s1" / "config.json").read_text())
    assert run["dataset_path"] == str(tmp_path / "dataset")  # where the data is, not the folder it was made in
    # a killed earlier run's debris (seqnet's mark) is removed; a user's files, marked or not like it, are kept
    dead = [tmp_path / "train_seqnet" / ".last.pt.seqnet-abc123.tmp", tmp_path / ".results.json.seqnet-x1.tmp"]
    keep = [tmp_path / ".results.json.x1.tmp", tmp_path / "notes.txt"]
    for p in dead + keep[:1]:
        p.write_text("left behind")
    assert cli_main(["demo", "--places", "200", "--epochs", "1", "--out", str(tmp_path), "--device", "cpu",
                     "--seed", "1"]) == 0  # an earlier demo's outputs are replaced
    assert json.loads((tmp_path / "results.json").read_text())["config"]["demo"]["seed"] == 1
    assert not [p for p in dead if p.exists()] and all(p.exists() for p in keep)
    assert not [p.name for p in tmp_path.parent.iterdir() if p.name.startswith(f".{tmp_path.name}.seqnet-")]


def test_demo_never_deletes_a_users_directory(tmp_path, capsys):
    (tmp_path / "train_s1").mkdir()
    (tmp_path / "train_s1" / "thesis.tex").write_text("precious")
    for extra in ([], ["--overwrite"]):  # not even when asked to overwrite: seqnet did not write it
        rc = cli_main(["demo", "--places", "200", "--epochs", "1", "--out", str(tmp_path), "--device", "cpu", *extra])
        err = capsys.readouterr().err
        assert rc == 2 and "train_s1/thesis.tex was not written by seqnet; refusing to replace" in err, err
        assert len(err.strip().splitlines()) == 1
        assert not (tmp_path / "dataset").exists()  # refused before any work
    assert (tmp_path / "train_s1" / "thesis.tex").read_text() == "precious"


def test_demo_replaces_only_what_a_demo_wrote(tmp_path, capsys, synth_dataset):
    """A seqnet dataset, a training run or results made elsewhere by the user, where the demo writes its own,
    are refused (with the hint) and kept; --overwrite replaces them."""
    from seqnet.data.io import save_dataset

    mine = save_dataset(synth_dataset, tmp_path / "dataset")
    before = {p: p.read_bytes() for p in mine.rglob("*") if p.is_file()}
    argv = ["demo", "--places", "200", "--no-train", "--out", str(tmp_path), "--device", "cpu"]
    assert cli_main(argv) == 2
    err = capsys.readouterr().err
    assert "dataset was written by another seqnet command" in err and "--overwrite" in err
    assert {p: p.read_bytes() for p in mine.rglob("*") if p.is_file()} == before
    assert not (tmp_path / "results.json").exists()
    (tmp_path / "train_seqnet").mkdir()
    for f in ("best.pt", "last.pt", "config.json"):  # a run of `seqnet train --out DIR/train_seqnet`
        (tmp_path / "train_seqnet" / f).write_text("my run")
    assert cli_main([*argv, "--overwrite"]) == 0  # the dataset is replaced; the run is not a --no-train output
    assert (tmp_path / "train_seqnet" / "best.pt").read_text() == "my run"
    capsys.readouterr()
    assert cli_main(["demo", "--places", "200", "--epochs", "1", "--out", str(tmp_path), "--device", "cpu"]) == 2
    assert "train_seqnet was written by another seqnet command" in capsys.readouterr().err
    assert cli_main(argv) == 0  # its own outputs: replaced without asking


def test_demo_without_training_gives_baselines_only(tmp_path):
    res = json.loads(main(DemoConfig(places=200, train_models=False, device="cpu"), tmp_path).read_text())
    assert list(res["methods"]) == [*BASELINES, MODEL_FREE_HVPR]
    assert res["config"]["train_seconds"] == {}


@pytest.mark.parametrize("kw, pattern", [({"places": 10}, "places"), ({"seq_len": 1}, "seq_len"),
                                         ({"w": 9}, "w must be"), ({"train_models": "no"}, "true or false")])
def test_demo_config_errors(kw, pattern):
    with pytest.raises(ConfigError, match=pattern):
        DemoConfig(**kw)
