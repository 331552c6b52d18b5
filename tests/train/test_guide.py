"""The guide in the training loop: the plan logged before training, the small-val warning, the stop on
epochs without an active triplet."""

from __future__ import annotations

import logging
import re

import pytest

from seqnet.train import TrainConfig, loop, train
from seqnet.train.config import RESUME_OVERRIDABLE
from seqnet.train.guide import (
    Plan,
    advice,
    epoch_flops,
    plan,
    plan_text,
    suggested_pca,
)
from seqnet.train.watch import inactive_epochs, inactive_message, val_warning

FAST = TrainConfig(optimizer="adam", lr=1e-2, batch_size=16, cache_refresh=40, n_neg_sample=50, seq_len=3, w=2,
                   out_dims=8, device="cpu", epochs=1)


def _plan(d: int, n_frames: int = 300, out: int | None = None, w: int = 3, available: int | None = 64 * 2**30,
          n_queries: int = 96, **kw) -> Plan:
    conf = TrainConfig(w=w, out_dims=out or d, **kw)
    p = plan(conf, d, n_queries, 196, n_frames, 2, 3, "cpu", rate=1e10)
    return Plan(**{**p.__dict__, "available": available})


def test_the_high_dimensional_case_of_the_issue_is_costed_and_advised():
    # D = 6400, S_5 w=3, SGD: the run that wrote 0.49 + 0.98 GB checkpoints (measured: 491548845 + 983109345 B)
    p = _plan(6400)
    assert p.weights == 6400 * 6400 * 3 + 6400
    assert abs(p.checkpoint_bytes - (491548845 + 983109345)) < 0.01 * p.checkpoint_bytes
    said = advice(p)
    assert any("--pca 128" in a and "4096" in a for a in said)  # D > 4096 and > the 96 + 196 training windows
    assert any("checkpoints take 1.4 GiB" in a for a in said)
    text = plan_text(p)  # the advice is logged apart (warnings), not in the INFO block
    assert "peak memory" in text and "per epoch" in text and "best.pt + last.pt" in text and "advice" not in text
    # and a small model on plenty of data has nothing to advise (the advice can be absent)
    small = _plan(256, n_frames=5000, available=None)
    assert advice(small) == [] and "advice" not in plan_text(small)


def test_pca_advice_below_4096_when_d_is_not_below_the_windows_the_layer_is_learnt_from():
    """The layer is learnt from the training queries and reference windows, not from every frame of the split:
    D = 512 on 96 + 196 windows among 600 frames was not advised (its frames were counted)."""
    said = advice(_plan(512, n_frames=600))
    assert len(said) == 1 and "--pca 256" in said[0], said
    assert "not below the 292 windows the layer is learnt from (96 training queries, 196 reference windows)" \
        in said[0] and "training frames" not in said[0] and "786,944 weights" in said[0], said
    assert advice(_plan(256, n_frames=600)) == []  # D below the windows: nothing to say
    assert suggested_pca(_plan(100000, n_frames=10**6, n_queries=10**5)) == 4096


def test_memory_advice_when_over_half_of_what_is_available():
    p = _plan(1024, n_frames=5000, available=2**20)
    assert any("peak memory" in a for a in advice(p))


def test_epoch_flops_against_a_naive_count():
    conf = TrainConfig(seq_len=5, w=3, out_dims=64, n_negatives=4, cache_refresh=10)
    d, nq, nr, nv = 32, 25, 40, 7
    window = 2 * 3 * d * 64  # one [D w] x [D w, out] product per window
    refreshes = 3  # ceil(25 / 10)
    naive = 0.0
    for _ in range(refreshes):
        naive += nr * window  # the reference windows, each refresh
    for _ in range(nq):
        naive += window + 2 * nr * 64  # the query's mining descriptor, its distances
        naive += 3 * (2 + 4) * window  # forward and backward of q, p and K negatives
    naive += nv * window
    assert epoch_flops(conf, d, nq, nr, nv) == pytest.approx(naive)


def test_val_warning_says_how_many_how_large_and_what_happens():
    assert val_warning(50, "ds[val]") is None
    msg = val_warning(6, "ds[val]")
    assert "6 queries" in msg and "50" in msg and "1/6" in msg and "--val-split none" in msg
    # resuming refuses --val-split (RESUME_OVERRIDABLE): the hint says the change is for a new run
    resumed = val_warning(6, "ds[val]", resumed=True)
    assert "a resumed run keeps its val split; in a new run, give a larger val split" in resumed, resumed
    assert "val_split" not in RESUME_OVERRIDABLE


def test_inactive_epochs_counts_the_trailing_run():
    hist = [{"active": 3.0}, {"active": 0.0}, {"active": 1.0}, {"active": 0.0}, {"active": 0.0}]
    assert inactive_epochs(hist) == 2 and inactive_epochs(hist[:3]) == 0 and inactive_epochs([]) == 0


@pytest.mark.filterwarnings(r"ignore:Detected call of `lr_scheduler.step\(\)`")
def test_training_stops_after_stop_inactive_epochs_without_an_active_triplet(synth_dataset, tmp_path, monkeypatch,
                                                                              caplog):
    def no_triplets(run, src, epoch):
        return {"loss": 0.0, "queries": float(src.n_queries), "skipped": 0.0, "triplets": 0.0, "active": 0.0}

    monkeypatch.setattr(loop, "train_epoch", no_triplets)
    caplog.set_level(logging.DEBUG, logger="seqnet")  # the end line is DEBUG (seqnet train prints the summary)
    run = train(synth_dataset, FAST.replace(epochs=10, stop_inactive=3), tmp_path / "r")
    assert run.epoch == 3 and (tmp_path / "r" / "best.pt").exists()
    said = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any("no active triplet for 3 epochs in a row" in m and "--margin" in m for m in said)
    # a direction: a larger --neg-radius gives fewer negatives (the hint said "more negatives (--neg-radius)")
    assert any(re.search(r"harder negatives: a smaller --neg-radius \(now [\d.]+; references farther than it are "
                         r"negatives\)", m) for m in said), said
    assert any("No triplet was active from the first epoch" in m for m in said) and run.advice[-1] in said
    assert any("stopped: no active triplet for 3 epochs" in r.getMessage() for r in caplog.records)
    # 0: never stops
    run = train(synth_dataset, FAST.replace(epochs=4, stop_inactive=0), tmp_path / "never")
    assert run.epoch == 4
    conf = FAST.replace(stop_inactive=3).resolve(synth_dataset)
    assert "0 active" not in inactive_message([{"epoch": 7, "triplets": 0.0, "active": 0.0}], conf, 5)


def test_the_plan_is_logged_once_before_training(synth_dataset, tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="seqnet")
    train(synth_dataset, FAST, tmp_path / "r")
    plans = [r.getMessage() for r in caplog.records if r.getMessage().startswith("training plan:")]
    assert len(plans) == 1 and "D 16->8" in plans[0] and "checkpoints" in plans[0]
    value, unit = plans[0].split("time         about ")[1].split(" per epoch")[0].split()
    seconds = float(value) / (1000 if unit == "ms" else 1)
    assert unit in ("ms", "s") and 0.01 < seconds < 60  # 7 batches of 16 and validation: about 0.2 s


def test_the_measured_rate_leaves_out_a_slow_start(monkeypatch: pytest.MonkeyPatch) -> None:
    """A process's first products are many times slower (its thread pool starting): the rate is timed after a
    warm-up of at least ``min_seconds``, on runs of products that last as long, not on the first product."""
    from seqnet.train import guide

    clock = {"t": 0.0, "calls": 0}

    class Product:
        def sum(self) -> Product:
            return self

        def item(self) -> float:
            clock["calls"] += 1
            clock["t"] += 0.005 if clock["calls"] <= 6 else 0.001  # six products of 5 ms, then 1 ms each
            return 0.0

    class Tensor:
        def __matmul__(self, other: object) -> Product:
            return Product()

    monkeypatch.setattr(guide.time, "perf_counter", lambda: clock["t"])
    monkeypatch.setattr(guide, "torch", type("T", (), {"randn": staticmethod(lambda *a, **k: Tensor())}))
    rate = guide.measured_rate(100, 100, "cpu", repeats=3, min_seconds=0.02)
    rows = int(min(65536, max(256, 1e8 // (2 * 100 * 100))))
    assert rate == pytest.approx(2.0 * rows * 100 * 100 / 0.001)  # the warm speed, not the slow start's
    assert clock["calls"] >= 6 + 3 * 20  # each timed run lasted at least min_seconds


def test_the_measured_rate_of_a_real_product_is_positive() -> None:
    rate = measured_rate_cpu()
    assert 1e6 < rate < 1e15


def measured_rate_cpu() -> float:
    from seqnet.train.guide import measured_rate

    return measured_rate(64, 64, "cpu", repeats=1, min_seconds=0.005)


def test_the_memory_estimate_caps_the_batch_at_the_training_queries(synth_dataset, monkeypatch):
    """--batch-size above the training queries makes the same batches: the estimate, the plan and the check
    count at most those queries (dsA's 56 queries with --batch-size 4096 were 'needs about 28.4 GiB')."""
    from seqnet.core.errors import ResourceError
    from seqnet.train.guide import Budget, check_memory
    from seqnet.train.memory import train_bytes

    conf = TrainConfig(seq_len=5, w=5, device="cpu")
    n = len(synth_dataset.split("train").query)
    huge, capped = conf.replace(batch_size=4096), conf.replace(batch_size=n)
    assert train_bytes(huge, 256, 500, 900, n_train=n) == train_bytes(capped, 256, 500, 900, n_train=n)
    assert train_bytes(huge, 256, 500, 900) > train_bytes(capped, 256, 500, 900)  # the frames cap the default
    held = Budget(300 << 20, None)  # the process's memory, the same for both
    assert plan(huge, 256, 56, 196, 300, 2, 3, "cpu", rate=1e10, budget=held).peak_bytes == \
        plan(conf.replace(batch_size=56), 256, 56, 196, 300, 2, 3, "cpu", rate=1e10, budget=held).peak_bytes
    d = synth_dataset.query.dim
    need = train_bytes(capped, d, len(synth_dataset.reference), len(synth_dataset.query), True, n)
    monkeypatch.setenv("SEQNET_MEMORY_MB", str(2 * need / 2**20))
    check_memory(huge, synth_dataset)  # fits: the batch is the train split's queries at most
    with pytest.raises(ResourceError, match="needs about"):
        check_memory(huge.replace(train_split="all", batch_size=10**6, out_dims=4096), synth_dataset)


def test_the_plan_counts_weights_in_one_format():
    """65568 and 131136 weights were '65568' and '0.1 M': every count is exact, with thousands separators."""
    small, large = _plan(256, out=64, w=4), _plan(6400)
    assert plan_text(small).startswith(f"training plan: S_5 (w=4, D 256->64): {256 * 64 * 4 + 64:,} weights, ")
    assert f"): {6400 * 6400 * 3 + 6400:,} weights, " in plan_text(large) and "122,886,400 weights" in plan_text(large)


def test_the_epoch_time_counts_the_update_and_the_checkpoints():
    """A large model's epoch is dominated by the optimiser's update and the checkpoint writes, not its FLOPs
    (D = 6400, w = 5: the plan said 10.6 s an epoch, the epochs took 37-41 s; with both terms 31 s)."""
    import dataclasses

    from seqnet.train.guide import STEP_SECONDS, WRITE_BYTES_PER_S, measured_update

    p = _plan(64)
    bare = dataclasses.replace(p, update_seconds=0.0, checkpoint_bytes=0)
    steps = -(-p.n_queries // p.batch_size)
    assert bare.epoch_seconds == pytest.approx(p.flops / p.rate + (steps + 1) * STEP_SECONDS)
    more = dataclasses.replace(p, update_seconds=0.5, checkpoint_bytes=int(2e9))
    assert more.epoch_seconds - bare.epoch_seconds == pytest.approx(steps * 0.5 + 2e9 / WRITE_BYTES_PER_S)
    small, big = measured_update(1 << 16, "adam", "cpu"), measured_update(1 << 24, "sgd", "cpu")
    assert 0 < small < 1 and 0 < big < 10


def test_the_memory_estimate_counts_the_updates_temporaries():
    from seqnet.train.config import TrainConfig
    from seqnet.train.memory import train_bytes

    adam = train_bytes(TrainConfig(optimizer="adam", w=5, out_dims=6400), 6400, 10, 10)
    sgd = train_bytes(TrainConfig(optimizer="sgd", w=5, out_dims=6400), 6400, 10, 10)
    weights = 6400 * 6400 * 5 + 6400
    assert adam >= 7 * 4 * weights and sgd >= 4 * 4 * weights and adam - sgd == 3 * 4 * weights


GiB = 2**30


def _wide(dim: int = 16384):
    """A synthetic dataset of ``dim``-D descriptors (16-D ones repeated: make_synthetic takes 74 s at 16384)."""
    import dataclasses

    import numpy as np

    from seqnet.data.synth import make_synthetic

    ds = make_synthetic(places=100, dim=16, seed=0)
    sides = {k: dataclasses.replace(t, descriptors=np.tile(t.descriptors, (1, dim // 16)))
             for k, t in (("reference", ds.reference), ("query", ds.query))}
    return dataclasses.replace(ds, **sides)


def _memory(monkeypatch, held: int, free: int) -> None:
    """What the process holds (VmRSS) and may still allocate, as the guide reads them."""
    from seqnet.train import guide

    monkeypatch.setattr(guide, "rss_bytes", lambda: held)
    monkeypatch.setattr(guide, "available_bytes", lambda: free)


def test_a_plan_over_the_available_memory_is_refused_and_the_check_agrees_with_the_plan(monkeypatch):
    """The issue: D = 16384, the plan said a peak of 20.9 GiB of 17.7 GiB available, advised, and trained. The
    check before any work refuses what the plan would put over what is available; between half and all, it
    lets the run start and the plan advises."""
    from seqnet.core.errors import ResourceError
    from seqnet.train.guide import Budget, check_memory

    ds = _wide()
    conf = TrainConfig(seq_len=5, w=5, device="cpu").resolve(ds)
    held = int(0.3 * GiB)
    _memory(monkeypatch, held, int(17.7 * GiB))
    with pytest.raises(ResourceError) as e:
        check_memory(conf, ds)
    msg = str(e.value)
    assert "\n" not in msg and "D=16384->16384" in msg and "needs about 20.6 GiB of memory" in msg, msg
    assert "(0.3 GiB held by this process before it + 20.3 GiB more), 18.0 GiB available" in msg, msg
    assert all(h in msg for h in ("--pca 32", "--out-dims", "--w", "--batch-size")), msg
    need = check_memory.__globals__["train_bytes"](conf, 16384, len(ds.reference), len(ds.query), True,
                                                   len(ds.split("train").query))
    for free in (need - 1, need, 2 * need - 1):  # the decision: refused iff the plan's peak is over its available
        _memory(monkeypatch, held, free)
        budget = None
        try:
            budget = check_memory(conf, ds)
        except ResourceError:
            pass
        p = plan(conf, 16384, len(ds.split("train").query), len(ds.split("train").reference), 80, 0, 1, "cpu",
                 len(ds.split("train").reference), len(ds.split("train").query), rate=1e10,
                 budget=Budget(held, free))
        assert (budget is None) == (free < need) and (p.peak_bytes > p.available) <= (budget is None), free
        if budget is not None:
            assert budget == Budget(held, free)
            assert any("is over half of the" in a for a in advice(p))  # between half and all: trained, advised


def test_the_plan_counts_what_the_process_holds_before_training(monkeypatch):
    """The peak was 16-90x too low on small runs (4 MiB planned, 361 MiB measured): it left out the process
    (Python, torch, the dataset: VmRSS at the check) and what training loads (torch.optim, TensorBoard)."""
    from seqnet.train.guide import Budget
    from seqnet.train.memory import LIBRARY_BYTES, train_bytes

    conf = TrainConfig(seq_len=5, w=3)
    p = plan(conf, 64, 96, 196, 300, 2, 3, "cpu", rate=1e10, budget=Budget(260 << 20, 10 * GiB))
    assert p.peak_bytes == (260 << 20) + train_bytes(conf, 64, 196, 96, True, 96) and p.held_bytes == 260 << 20
    assert train_bytes(conf, 64, 196, 96) > LIBRARY_BYTES > 64 << 20 and p.available == 10 * GiB + (260 << 20)
    assert "peak memory  about 357 MiB (260 MiB held before training) of 10.3 GiB available" in plan_text(p)
    _memory(monkeypatch, 123 << 20, GiB)  # without a budget: the process now
    assert plan(conf, 64, 96, 196, 300, 2, 3, "cpu", rate=1e10).held_bytes == 123 << 20


def test_training_over_the_available_memory_is_refused_by_the_cli_before_any_work(tmp_path, monkeypatch, capsys):
    """Exit 1, one line naming the estimate, what is available and the flags; no model, no run written."""
    from seqnet.cli import main as cli_main
    from seqnet.data.io import save_dataset

    data = save_dataset(_wide(), tmp_path / "ds")
    _memory(monkeypatch, int(0.3 * GiB), int(17.7 * GiB))
    made = []
    monkeypatch.setattr(loop, "open_run", lambda *a, **k: made.append(a))
    capsys.readouterr()
    rc = cli_main(["train", "--dataset", str(data), "--out", str(tmp_path / "run"), "--seq-len", "5", "--w", "5",
                   "--epochs", "1", "--device", "cpu"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1, (rc, err)
    assert "needs about 20.6 GiB of memory" in err[0] and "18.0 GiB available" in err[0], err
    assert "--pca 32 (saves about 20.2 GiB; seqnet train, or seqnet dataset from-images)" in err[0], err
    assert "--out-dims" in err[0], err
    assert not made and not list(tmp_path.glob("run/*.pt")) and not (tmp_path / "run" / "config.json").exists()


def test_training_between_half_and_all_of_the_memory_trains_and_advises(tmp_path, monkeypatch, capsys):
    from seqnet.cli import main as cli_main
    from seqnet.data.io import save_dataset
    from seqnet.data.synth import make_synthetic
    from seqnet.train.memory import LIBRARY_BYTES

    data = save_dataset(make_synthetic(places=200, dim=8), tmp_path / "ds")
    _memory(monkeypatch, 10 << 20, int(1.5 * LIBRARY_BYTES))  # the run needs a little over LIBRARY_BYTES
    rc = cli_main(["--threads", "1", "train", "--dataset", str(data), "--out", str(tmp_path / "run"),
                   "--epochs", "1", "--out-dims", "8", "--device", "cpu"])
    err = capsys.readouterr().err
    assert rc == 0 and (tmp_path / "run" / "best.pt").exists(), err
    assert "advice: the estimated peak memory" in err and "is over half of the" in err, err


def test_the_plan_logged_is_against_the_memory_checked_before_the_model_was_made(synth_dataset, tmp_path,
                                                                                   monkeypatch, caplog):
    """The plan read the memory after the model and the data were on the device (17.7 GiB of what had been more
    at the check): a peak over it, yet trained. It now states the check's budget."""
    from seqnet.train import guide

    frees = iter([10 * GiB])  # the check's reading; a second one would be 1 MiB
    monkeypatch.setattr(guide, "rss_bytes", lambda: 100 << 20)
    monkeypatch.setattr(guide, "available_bytes", lambda: next(frees, 1 << 20))
    caplog.set_level(logging.INFO, logger="seqnet")
    train(synth_dataset, FAST, tmp_path / "r")
    plans = [r.getMessage() for r in caplog.records if r.getMessage().startswith("training plan:")]
    assert len(plans) == 1 and "(100 MiB held before training) of 10.1 GiB available" in plans[0], plans
