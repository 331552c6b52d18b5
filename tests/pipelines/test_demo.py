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
    (tmp_path / "train_seqnet").mkdir()
    (tmp_path / "train_seqnet" / "last.pt").write_text("a previous demo's run: replaced")
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


def test_demo_never_deletes_a_users_directory(tmp_path, capsys):
    (tmp_path / "train_s1").mkdir()
    (tmp_path / "train_s1" / "thesis.tex").write_text("precious")
    rc = cli_main(["demo", "--places", "200", "--epochs", "1", "--out", str(tmp_path), "--device", "cpu"])
    err = capsys.readouterr().err
    assert rc == 2 and "seqnet did not write (first: thesis.tex)" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "dataset").exists()  # refused before any work
    assert (tmp_path / "train_s1" / "thesis.tex").read_text() == "precious"


def test_demo_without_training_gives_baselines_only(tmp_path):
    res = json.loads(main(DemoConfig(places=200, train_models=False, device="cpu"), tmp_path).read_text())
    assert list(res["methods"]) == [*BASELINES, MODEL_FREE_HVPR]
    assert res["config"]["train_seconds"] == {}


@pytest.mark.parametrize("kw, pattern", [({"places": 10}, "places"), ({"seq_len": 1}, "seq_len"),
                                         ({"w": 9}, "w must be"), ({"train_models": "no"}, "true or false")])
def test_demo_config_errors(kw, pattern):
    with pytest.raises(ConfigError, match=pattern):
        DemoConfig(**kw)
