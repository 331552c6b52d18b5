"""The demo trains S_L and S_1 and shows the learned methods next to the baselines."""

from __future__ import annotations

import json

import pytest
import torch

from seqnet.cli import main as cli_main
from seqnet.pipelines.demo import BASELINES, DEMO_METHODS, LEARNED, run_demo


@pytest.fixture
def keep_threads():
    """The demo CLI sets torch's thread count (default 1); restore it for the other tests."""
    n = torch.get_num_threads()
    yield
    torch.set_num_threads(n)


def test_cli_demo_trains_and_evaluates_every_method(tmp_path, capsys, keep_threads):
    assert DEMO_METHODS == BASELINES + LEARNED
    (tmp_path / "train_seqnet").mkdir()
    (tmp_path / "train_seqnet" / "last.pt").write_text("a previous demo's run: replaced")
    assert cli_main(["demo", "--places", "200", "--epochs", "1", "--out", str(tmp_path), "--device", "cpu"]) == 0
    out = capsys.readouterr().out
    for method in DEMO_METHODS:
        assert f"\n{method} " in out
    assert "trained on the train split" in out
    saved = json.loads((tmp_path / "results.json").read_text())
    assert list(saved["methods"]) == DEMO_METHODS
    assert all(0.0 <= m["recall@1"] <= 1.0 for m in saved["methods"].values())
    cfg = saved["config"]
    assert cfg["models"]["s1"]["seq_len"] == 1 and cfg["models"]["seqnet"]["seq_len"] == 5
    assert set(cfg["train_seconds"]) == {"seqnet", "s1"} and cfg["demo_train"]["epochs"] == 1
    for role in ("seqnet", "s1"):
        assert (tmp_path / f"train_{role}" / "best.pt").is_file()


def test_run_demo_without_training_gives_baselines_only():
    ev = run_demo(None, places=200, train_models=False, device="cpu")
    assert list(ev.results["methods"]) == [*BASELINES, "hvpr-delta:raw+seqmatch"]
    assert ev.results["config"]["train_seconds"] == {}
