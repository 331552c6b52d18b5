"""Memory estimates refused before the work (one line, exit 1, nothing written)."""

from __future__ import annotations

import pytest

from seqnet.cli import main as cli
from seqnet.core import memory
from seqnet.core.errors import ResourceError
from seqnet.data.io import save_dataset
from seqnet.train.config import TrainConfig, train_bytes


def test_available_memory_is_the_lowest_known_limit(monkeypatch):
    free = memory.available_bytes()
    assert free is None or free > 0
    monkeypatch.setenv("SEQNET_MEMORY_MB", "10")
    assert memory.available_bytes() == 10 * 2**20
    with pytest.raises(ResourceError, match=r"x needs about 1\.0 GiB of memory, 0\.0 GiB available; hint: h"):
        memory.check_fits(2**30, "x", "h")
    memory.check_fits(2**20, "x", "h")


def test_the_training_estimate_grows_with_the_model():
    conf = TrainConfig(seq_len=5, w=5, optimizer="adam")
    wide = train_bytes(conf, 19200, 222)
    assert wide > 4 * 4 * 19200 * 19200 * 5  # the weights, their gradients and Adam's two moments
    assert train_bytes(conf.replace(out_dims=512), 19200, 222) < wide / 10
    assert train_bytes(conf.replace(optimizer="sgd"), 19200, 222) < wide


def test_training_that_cannot_fit_is_refused_before_anything_is_written(synth_dataset, tmp_path, monkeypatch, capsys):
    data = save_dataset(synth_dataset, tmp_path / "ds")
    monkeypatch.setenv("SEQNET_MEMORY_MB", "0.01")  # 10 kB: less than this tiny run needs
    assert cli(["train", "--dataset", str(data), "--epochs", "1", "--out", str(tmp_path / "run")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "needs about" in err[0] and "--out-dims" in err[0], err
    assert not (tmp_path / "run").exists()
