"""The memory a training run needs (seqnet.train.memory): the batch term against what a step really allocates,
and the hint that names what lowers the estimate."""

from __future__ import annotations

import dataclasses
import gc
import multiprocessing
import sys

import numpy as np
import pytest

from seqnet.train import TrainConfig, train
from seqnet.train.memory import train_bytes


def _wide(dim: int):
    from seqnet.data.synth import make_synthetic

    ds = make_synthetic(places=120, dim=16, seed=0)
    sides = {k: dataclasses.replace(t, descriptors=np.tile(t.descriptors, (1, dim // 16)))
             for k, t in (("reference", ds.reference), ("query", ds.query))}
    return dataclasses.replace(ds, **sides)


def _status(key: str) -> int:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) * 1024 for line in f if line.startswith(key))


def _step_peaks(dim: int, conf: TrainConfig, out_dir) -> list[tuple[int, int, int]]:
    """(queries, triplets, peak bytes above the resident memory before it) of every optimiser step of training
    ``conf`` on :func:`_wide` ``(dim)``, in the process that calls it (the test runs it in a fresh one)."""
    import seqnet.train.epoch as epoch

    peaks, step = [], epoch.train_step

    def measured(run, src, rows, mined, total=None):
        gc.collect()
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")  # VmHWM := VmRSS
        base = _status("VmRSS:")
        stats = step(run, src, rows, mined, total)
        peaks.append((len(rows), int(mined.valid.sum()), _status("VmHWM:") - base))
        return stats

    epoch.train_step = measured
    try:
        train(_wide(dim), conf, out_dir)
    finally:
        epoch.train_step = step
    return peaks


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads and resets VmHWM in /proc/self")
def test_the_batch_term_is_what_a_step_allocates(tmp_path, seq_len=5, w=5):
    """The batch was costed 3 L x more than a step allocates (windows are averaged before the layer): a 1.3 GiB
    run (D = 8192 -> 512, w = 5, batch 146) refused as 4.7 GiB. The step's peak at two batch sizes: its growth per
    window is the estimate's within 30 %. Each batch size is measured in a fresh process: in a long-lived one
    (the whole suite) memory freed earlier is reused and a step's new resident memory understates what it
    allocates (9.8 D floats a window measured there, 14.5 alone)."""
    d = 2048
    conf = TrainConfig(seq_len=seq_len, w=w, out_dims=64, n_neg_sample=50, device="cpu", epochs=1,
                       val_split="none", cache_refresh=0)
    per = {}
    for b in (8, 48):
        with multiprocessing.get_context("spawn").Pool(1) as pool:
            peaks = pool.apply(_step_peaks, (d, conf.replace(batch_size=b), tmp_path / f"b{b}"))
        q, t, peak = max((p for p in peaks if p[0] == b), key=lambda p: p[2])
        per[b] = (2 * q + t, peak)
    (n1, p1), (n2, p2) = per[8], per[48]
    measured = (p2 - p1) / (n2 - n1)  # bytes per window of the batch
    big = conf.resolve(_wide(d)).replace(batch_size=48)
    planned = (train_bytes(big, d, 240, 240, n_train=60) - train_bytes(big.replace(batch_size=8), d, 240, 240,
                                                                        n_train=60)) / (40 * 12)
    assert 0.75 < planned / measured < 1.3, (planned / 4 / d, measured / 4 / d)


def test_the_hint_names_the_largest_savings_first_and_never_the_value_given():
    """--out-dims 512 given, refused with 'a smaller --out-dims (e.g. 512)' and --batch-size (the real cost) last."""
    from seqnet.train.memory import memory_hint

    conf = TrainConfig(seq_len=5, w=5, out_dims=512, batch_size=146)
    hint = memory_hint(conf, 8192, 300, 300, 146, True, 256)
    flags = [part.split(" (")[0] for part in hint.split("), ")]
    assert "--out-dims 512" not in hint and "--out-dims 256" in flags, hint
    assert flags.index("--batch-size 36") < flags.index("--out-dims 256"), hint
    assert "--optimizer" not in hint and "saves about" in hint
    s1 = memory_hint(TrainConfig(seq_len=1, w=1, out_dims=8, batch_size=1), 8, 30, 30, 10, True, 8)
    assert "--w 1" not in s1 and "--batch-size" not in s1 and "--pca" not in s1 and "--out-dims" not in s1, s1


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads and resets VmHWM in /proc/self")
@pytest.mark.parametrize("name", ["sgd", "adam"])
def test_the_optimiser_step_holds_the_weight_copies_costed(name, n=1 << 23):
    """Adam was costed 6 weight-sized arrays at its step, which holds 7 (the weights, the gradient, the weight
    decay's sum, two moments, the update's sqrt and quotient): D = 8192 S_5 w = 3 planned 5.2 GiB, peaked at
    5.78. The first step of the project's optimiser (it allocates the state) on n weights: the weight-sized
    arrays at its peak, the weights included."""
    import torch

    from seqnet.train.config import OPTIMIZERS
    from seqnet.train.memory import WEIGHT_COPIES

    param = torch.nn.Parameter(torch.randn(n))
    opt = OPTIMIZERS[name]([param], TrainConfig(optimizer=name))
    gc.collect()
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")  # VmHWM := VmRSS
    base = _status("VmRSS:")
    (param * 2.0).sum().backward()  # the gradient: one weight-sized array
    opt.step()
    copies = 1 + (_status("VmHWM:") - base) / (4 * n)
    assert abs(copies - WEIGHT_COPIES[name]) < 0.5, (name, copies, WEIGHT_COPIES[name])
