"""What training says while it runs and how it reaches a Python caller (seqnet.train.watch, the guide's advice)."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest

from seqnet.train import TrainConfig, loop, train
from seqnet.train.watch import inactive_message

FAST = TrainConfig(optimizer="adam", lr=1e-2, batch_size=16, cache_refresh=40, n_neg_sample=50, seq_len=3, w=2,
                   out_dims=8, device="cpu", epochs=1)


def _epoch(epoch: int, active: float, r1: float) -> dict:
    return {"epoch": epoch, "loss": 0.1 * active, "triplets": active, "active": active, "recall@1": r1}


def test_a_model_that_separated_its_training_set_is_not_told_its_data_is_too_easy():
    """A model that learnt until every training triplet was satisfied (loss 0, val R@1 still rising) was told
    'Likely: too little or too easy training data': the message says it separated the training queries, which
    epoch best.pt holds, and more training data first."""
    conf = TrainConfig(stop_inactive=3, margin=0.3, neg_radius=20.0)
    hist = [_epoch(1, 40, 0.5), _epoch(2, 9, 0.6), _epoch(3, 0, 0.7), _epoch(4, 0, 0.75), _epoch(5, 0, 0.8)]
    msg = inactive_message(hist, conf, 146, best_epoch=5)
    assert "too easy" not in msg and "too little" not in msg, msg
    assert "every training triplet is satisfied" in msg and "separated its 146 training queries" in msg, msg
    assert "active triplets until epoch 2" in msg and "best.pt holds epoch 5 (the last: val R@1 was still rising)" \
        in msg and "val R@1 0.8000" in msg, msg
    assert msg.index("more training queries") < msg.index("--margin (now 0.3)") and "\n" not in msg, msg
    early = inactive_message(hist[:4] + [_epoch(5, 0, 0.6)], conf, 146, best_epoch=4)
    assert "best.pt holds epoch 4, val R@1 0.7500" in early and "rising" not in early, early
    never = inactive_message([_epoch(1, 0, 0.2), _epoch(2, 0, 0.2), _epoch(3, 0, 0.2)], conf, 30, best_epoch=1)
    assert "No triplet was active from the first epoch" in never and "too easy for the margin" in never, never
    assert "--neg-radius (now 20;" in never, never
    unvalidated = inactive_message(hist, conf.replace(val_split="none"), 146)
    assert "best.pt = last.pt (no validation)" in unvalidated, unvalidated


@pytest.mark.filterwarnings(r"ignore:Detected call of `lr_scheduler.step\(\)`")
def test_the_advice_reaches_a_python_caller_once_and_stays_in_the_run(synth_dataset, tmp_path, caplog):
    """train() from Python logged the advice in the INFO plan block, which Python shows no one without a handler:
    it is now one warning each (once: not in the block too) and kept in run.advice."""
    caplog.set_level(logging.INFO, logger="seqnet")
    conf = FAST.replace(out_dims=None, n_neg_sample=20)
    sides = {k: dataclasses.replace(t, descriptors=np.tile(t.descriptors, (1, 32)))
             for k, t in (("reference", synth_dataset.reference), ("query", synth_dataset.query))}
    wide = dataclasses.replace(synth_dataset, **sides)  # D = 512, over its training windows
    run = train(wide, conf, tmp_path / "r")
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    advised = [m for m in warned if m.startswith("advice: D = 512 is not below the ")]
    assert len(advised) == 1 and advised[0] in run.advice, (warned, run.advice)
    block = next(r.getMessage() for r in caplog.records if r.getMessage().startswith("training plan:"))
    assert "advice" not in block, block
    assert any(a.startswith("the val split") for a in run.advice), run.advice
    # resuming: the val warning names what a resumed run accepts (it refuses --val-split)
    caplog.clear()
    resumed = train(wide, conf.replace(epochs=2), tmp_path / "r", resume=True)
    said = [a for a in resumed.advice if a.startswith("the val split")]
    assert said and "a resumed run keeps its val split; in a new run" in said[0], resumed.advice
    assert loop.train is train
