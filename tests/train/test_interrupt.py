"""Ctrl-C during ``seqnet train``: it said only "seqnet train: interrupted"; it says the epoch, what the run folder
holds and how to continue (:func:`seqnet.train.loop._epochs`)."""

from __future__ import annotations

import pytest

from seqnet.cli import main
from seqnet.data.io import save_dataset
from seqnet.data.synth import make_synthetic
from seqnet.train import loop

ARGS = ["--seq-len", "1", "--w", "1", "--out-dims", "8", "--epochs", "3", "--batch-size", "16", "--device", "cpu"]


@pytest.mark.parametrize("at, said", [
    (2, "during epoch 2 of 3: {run} holds last.pt of epoch 1 (best.pt: epoch 1); continue with seqnet train "
        "--resume {run}"),
    (1, "during epoch 1 of 3: no epoch was finished; {run} can be trained into again"),
])
def test_an_interrupted_run_says_what_it_holds_and_how_to_go_on(tmp_path, monkeypatch, capsys, at, said):
    data = save_dataset(make_synthetic(places=120, dim=8), tmp_path / "ds")
    real = loop.train_epoch

    def interrupted(run, src, epoch):
        if epoch == at:
            raise KeyboardInterrupt
        return real(run, src, epoch)

    monkeypatch.setattr(loop, "train_epoch", interrupted)
    run = tmp_path / "run"
    assert main(["-q", "train", "--dataset", str(data), "--out", str(run), *ARGS]) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == "seqnet train: interrupted " + said.format(run=run)
