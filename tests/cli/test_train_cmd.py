"""``seqnet train`` options: ``--seq-len`` below the default w without ``--w`` trains with w = L (it said "w must
be an integer in 1..1, got 3", a 3 the user never gave); ``--val-split test`` is said to make the test numbers
optimistic, at train and at eval."""

from __future__ import annotations

import json
import logging

from seqnet.cli import main as cli_main
from seqnet.cli.train_cmd import default_w
from seqnet.data.io import save_dataset
from seqnet.data.synth import make_synthetic
from seqnet.train.config import TrainConfig

ARGS = ["--epochs", "1", "--out-dims", "8", "--optimizer", "adam", "--lr", "1e-2", "--n-neg-sample", "50",
        "--cache-refresh", "40", "--device", "cpu"]


def test_default_w_fits_in_a_short_window():
    d = TrainConfig().w
    assert d == 3
    assert default_w(1, None) == 1 and default_w(2, None) == 2
    assert default_w(3, None) is None and default_w(None, None) is None  # the default (3) fits
    assert default_w(1, 1) == 1 and default_w(5, 2) == 2 and default_w(1, 3) == 3  # as given (1, 3: refused later)


def test_s1_without_w_and_the_test_split_as_val(tmp_path, capsys, caplog):
    data = save_dataset(make_synthetic(places=200, dim=8), tmp_path / "ds")
    run = tmp_path / "run"
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        assert cli_main(["-q", "--threads", "1", "train", "--dataset", str(data), "--seq-len", "1", "--val-split",
                         "test", "--out", str(run), *ARGS]) == 0
    cfg = json.loads((run / "config.json").read_text())
    assert (cfg["seq_len"], cfg["w"]) == (1, 1)
    said = [r.getMessage() for r in caplog.records]
    assert any("--val-split test: choosing the epoch on the test split makes its test numbers optimistic" in s
               for s in said), said
    caplog.clear()
    capsys.readouterr()
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        assert cli_main(["eval", "--dataset", str(data), "--model", str(run / "best.pt"), "--method", "single,s1",
                         "--json", str(tmp_path / "r.json")]) == 0
    line = "are queries the S_1 model"
    assert any(line in r.getMessage() and "choosing the epoch on the test split" in r.getMessage()
               for r in caplog.records), [r.getMessage() for r in caplog.records]
    assert any(line in w for w in json.loads((tmp_path / "r.json").read_text())["warnings"])
