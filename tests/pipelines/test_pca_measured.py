"""An explicit ``--pca D`` (``seqnet train --pca``, ``seqnet dataset from-images --pca``) is measured when it is
written: the model-free val R@1 before and after the very PCA written, said (WARNING when it loses queries) and
recorded in dataset.json's ``pca`` entry; the descriptor choice says its figures come before the PCA.

Session 53 hunt G1: own_data.md's ``from-images --pca 256`` on 2048-D pixels lowered val single R@1 0.650 -> 0.525
and raw+seqmatch 1.000 -> 0.972 without a word."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest
from PIL import Image

from seqnet.cli import main as cli_main
from seqnet.data.io import load_dataset, save_dataset
from seqnet.data.synth import make_synthetic
from seqnet.pipelines.pca import main


@pytest.fixture(scope="module")
def wide():
    """150 places, D = 512: a PCA to 32 loses val queries (tests/train/test_pca_cost.py)."""
    return make_synthetic(places=150, dim=512, seed=3)


def _warnings(caplog):
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


def test_train_pca_says_and_records_what_it_costs(wide, tmp_path, caplog):
    from seqnet.eval.config import EvalConfig
    from seqnet.eval.score import score
    from seqnet.train.pca_cost import MEASURED

    caplog.set_level(logging.INFO, logger="seqnet")
    out = main(save_dataset(wide, tmp_path / "ds"), 32)
    cost = load_dataset(out).extra["pca"]["cost"]
    said = _warnings(caplog)
    assert cost["lost"] and cost["split"] == "val" and said == [cost["text"]], said
    assert said[0].startswith(f"--pca 32 lowers single val R@1 {cost['before']['single']:.3f} -> "
                              f"{cost['after']['single']:.3f}") and "hint: drop --pca, or a larger D" in said[0]
    assert cost["after"]["single"] < cost["before"]["single"]
    conf = EvalConfig(methods=MEASURED, seq_len=5)  # the figures are eval's on the written dataset and the source
    for ds, want in ((wide, cost["before"]), (load_dataset(out), cost["after"])):
        got = score(ds.split("val"), conf, {}).results["methods"]
        assert {m: float(got[m]["recall@1"]) for m in MEASURED} == want
    caplog.clear()
    assert main(tmp_path / "ds", 32) == out and _warnings(caplog) == [cost["text"]]  # reused: said again


def test_a_pca_that_costs_nothing_is_said_at_info(wide, tmp_path, caplog, monkeypatch):
    from seqnet.train import pca_cost
    from seqnet.train.pca_cost import MEASURED

    monkeypatch.setattr(pca_cost, "_recalls", lambda part, conf: ({m: 0.9 for m in MEASURED},
                                                                 {m: 20 for m in MEASURED}))
    caplog.set_level(logging.INFO, logger="seqnet")
    out = main(save_dataset(wide, tmp_path / "ds"), 32)
    cost = load_dataset(out).extra["pca"]["cost"]
    assert not cost["lost"] and not _warnings(caplog)
    assert cost["text"].startswith("--pca 32 keeps single val R@1 0.900 -> 0.900")
    assert cost["text"] in [r.getMessage() for r in caplog.records]


@pytest.fixture(scope="module")
def route(tmp_path_factory):
    """40 places, two reference frames each, one query each (tests/pipelines/test_own_data.py's route)."""
    root = tmp_path_factory.mktemp("own")
    rng = np.random.default_rng(0)
    places = rng.random((40, 16, 32, 3))
    for side in ("ref", "qry"):
        (root / side).mkdir()
    for j in range(80):
        img = places[j // 2] * 0.9 + 0.1 * rng.random((16, 32, 3))
        Image.fromarray((img * 255).astype(np.uint8)).save(root / "ref" / f"r{j:03d}.png")
    for i in range(40):
        img = np.clip(places[i] * 0.6 + 0.2 + 0.15 * rng.random((16, 32, 3)), 0, 1)
        Image.fromarray((img * 255).astype(np.uint8)).save(root / "qry" / f"q{i:03d}.png")
    (root / "positives.json").write_text(json.dumps([[2 * i, 2 * i + 1] for i in range(40)]))
    return root


SPLITS = ["--split", "train=0:40,0:20", "--split", "val=40:80,20:40"]


def test_from_images_pca_is_measured_said_and_recorded(route, tmp_path, caplog, capsys):
    caplog.set_level(logging.INFO, logger="seqnet")
    argv = ["dataset", "from-images", str(route / "ref"), str(route / "qry"), "--method", "pixels", "--patch", "0",
            "--positives", str(route / "positives.json"), *SPLITS, "--pca", "8", "--out", str(tmp_path / "ds")]
    assert cli_main(argv) == 0
    cost = json.loads((tmp_path / "ds" / "dataset.json").read_text())["pca"]["cost"]
    assert cost["split"] == "val" and set(cost["before"]) == {"single", "raw+seqmatch"}
    assert cost["text"] in [r.getMessage() for r in caplog.records]
    assert (cost["text"] in _warnings(caplog)) == cost["lost"]
    assert ("(warned above)" in capsys.readouterr().out) == cost["lost"]


def test_the_descriptor_choice_says_its_figures_come_before_the_pca(route, tmp_path, monkeypatch):
    from seqnet.cli.dataset_cmd import images as images_cmd

    monkeypatch.setattr(images_cmd, "CANDIDATES", ("pixels",))
    argv = ["-q", "dataset", "from-images", str(route / "ref"), str(route / "qry"), "--patch", "0",
            "--positives", str(route / "positives.json"), *SPLITS, "--pca", "8", "--out", str(tmp_path / "ds")]
    assert cli_main(argv) == 0
    meta = json.loads((tmp_path / "ds" / "dataset.json").read_text())
    choice = meta["descriptor_choice"]
    assert choice["before_pca"] == 8 and "these figures are before --pca 8" in choice["reason"]
    assert "cost" in meta["pca"]  # the chosen descriptor after the PCA
