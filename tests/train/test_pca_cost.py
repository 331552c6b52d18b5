"""The guide's PCA advice, measured before it is given (seqnet.train.pca_cost), one suggested PCA size in every
message, and ``seqnet train --pca`` refusing before it writes the reduced dataset."""

from __future__ import annotations

import numpy as np
import pytest

from seqnet.data.io import load_dataset, save_dataset
from seqnet.data.synth import make_synthetic
from seqnet.train import TrainConfig, train
from seqnet.train.pca_cost import MEASURED, pca_advice, pca_cost

CONF = TrainConfig(optimizer="adam", lr=1e-3, batch_size=16, n_neg_sample=50, seq_len=5, w=3, out_dims=16,
                   device="cpu", epochs=1)


@pytest.fixture(scope="module")
def wide():
    """150 places, D = 512 (the own-data case of session 52, smaller: D not below the training windows)."""
    return make_synthetic(places=150, dim=512, seed=3)


def test_a_pca_that_costs_the_model_free_recall_is_not_advised(wide, tmp_path):
    """Session 52 M3: the guide advised ``--pca 128`` from shapes alone (D against the windows); following it cost
    single R@1 1.000 -> 0.674 on ``seqnet synth hd``. Now it measures first and says the cost instead."""
    run = train(wide, CONF, tmp_path / "run")
    said = [a for a in run.advice if "--pca" in a]
    assert said and not any("reduce it with --pca" in a or "reduce D with --pca" in a for a in said), run.advice
    cost = pca_cost(wide, CONF, 64)
    assert cost is not None and not cost.cheap and cost.split == "val"
    assert cost.after["single"] < cost.before["single"]
    text = said[0]
    assert "not below the" in text and "so it is not advised here" in text and "--w 1" in text, text
    assert f"--pca 64 would lower single val R@1 {cost.before['single']:.3f} -> {cost.after['single']:.3f}" \
        in text, text


def test_the_cost_is_what_eval_gives_on_the_pca_dataset(wide, tmp_path):
    """The same numbers as the evaluation: the model-free methods on the val split of the dataset --pca writes
    (after) and of the dataset itself (before, what eval's unreduced notice scores)."""
    from seqnet.eval.config import EvalConfig
    from seqnet.eval.score import score
    from seqnet.pipelines.pca import reduce_dataset

    cost = pca_cost(wide, CONF, 32)
    reduced, _ = reduce_dataset(wide, 32, "train")
    conf = EvalConfig(methods=MEASURED, seq_len=CONF.seq_len)
    for ds, want in ((wide, cost.before), (reduced, cost.after)):
        got = score(ds.split("val"), conf, {}).results["methods"]
        assert {m: float(got[m]["recall@1"]) for m in MEASURED} == want


def test_a_cheap_pca_is_advised_with_what_it_keeps(monkeypatch):
    from seqnet.train import pca_cost as module
    from seqnet.train.guide import advice, plan

    ds = make_synthetic(places=150, dim=256, seed=3)
    same = {m: 0.9 for m in MEASURED}
    monkeypatch.setattr(module, "_recalls", lambda part, conf: (same, {m: 20 for m in MEASURED}))
    p = plan(CONF.merge(out_dims=256), 256, 80, 100, 200, 20, 1, "cpu", rate=1e10)
    said = advice(p, pca_advice(ds, CONF, 64))
    assert any("reduce it with --pca 64" in a and "--pca 64 would keep single val R@1 0.900 -> 0.900" in a
               for a in said), said


def test_on_a_reduced_dataset_the_advice_names_the_unreduced_one(wide, tmp_path):
    """Session 52 L3: on ds2-pca179 the guide advised --pca 128, reducing a second time, without naming ds2."""
    from seqnet.pipelines.pca import main as reduce_main

    src = save_dataset(wide, tmp_path / "ds")
    once = reduce_main(src, 150)
    run = train(load_dataset(once), CONF, tmp_path / "run", dataset_path=once)
    said = " ".join(run.advice)
    assert f"seqnet train --dataset {src} --pca 64" in said, run.advice
    assert "of synthetic;" in said or "queries of synthetic" in said, run.advice  # measured on the unreduced one


def test_one_pca_size_in_every_message(monkeypatch):
    """Session 52 L3: for 180 train frames of 4096-D descriptors the --pca refusal said 89, the memory refusal 64
    and the guide 128."""
    from seqnet.core.errors import ConfigError, ResourceError
    from seqnet.pipelines.pca import check_fit_frames
    from seqnet.train import guide
    from seqnet.train.guide import Budget, check_memory, plan, suggested_pca

    ds = make_synthetic(places=100, dim=4096, seed=1)
    part = ds.split("train")
    frames = len(part.reference) + len(part.query)
    with pytest.raises(ConfigError) as refused:
        check_fit_frames(frames, frames)
    p = plan(CONF.merge(out_dims=4096), 4096, len(part.query), len(part.reference), frames, 10, 1, "cpu", rate=1e10,
             budget=Budget(0, 1 << 40))
    size = suggested_pca(p)
    monkeypatch.setattr(guide.Budget, "now", classmethod(lambda cls: Budget(0, 1 << 20)))
    with pytest.raises(ResourceError) as memory:
        check_memory(CONF.merge(out_dims=4096).resolve(ds), ds)
    assert f"--pca {size} or" in str(refused.value) and f"--pca {size} (saves" in str(memory.value)
    assert f"--pca {size} (saves" in p.memory_hint
    assert size == 2 ** int(np.log2((frames - 1) // 2))


def test_train_pca_refused_on_its_positions_writes_nothing(tmp_path, capsys):
    """Session 52 M4: ``seqnet train --dataset dsdeg --pca 64`` wrote dsdeg-pca64 (+ .pca.npz), then refused: no
    query had a positive and a negative."""
    from seqnet.cli import main as cli_main

    src = save_dataset(make_synthetic(places=100, dim=32, seed=1), tmp_path / "ds")
    rc = cli_main(["train", "--dataset", str(src), "--pca", "8", "--pos-radius", "0.001", "--neg-radius", "1e6",
                   "--out", str(tmp_path / "run"), "--device", "cpu", "--epochs", "1"])
    err = capsys.readouterr().err
    assert rc == 2 and "none of" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]
