"""The nordland64 cache (descriptors + flipped descriptors, PCA + models) is reused only whole: a run killed at
any rename, or failing in training, leaves a cache that the next run either reuses as one run wrote it or
rebuilds; never a new dataset beside old flipped descriptors, never a new S_L beside an old S_1. Entries the
cache did not make (a user's own dataset or run) are never replaced."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import each_crash_point, restorer, shared_data

from seqnet.core.errors import OutputError
from seqnet.pipelines.nordland64 import Nordland64Config, build_dataset, train_models
from seqnet.pipelines.nordland64 import cache as nc
from seqnet.pipelines.nordland64.config import TRAIN
from seqnet.pipelines.nordland64.models import train_key
from seqnet.sequence.checkpoints import read_checkpoint

FAST = {"epochs": 1, "n_neg_sample": 50, "n_negatives": 2, "batch_size": 8}
TINY = Nordland64Config(train_range=(0, 16), val_range=(18, 28), test_range=(30, 36), pca_dims=8, device="cpu",
                        train=TRAIN.replace(**FAST), train_s1=TRAIN.replace(seq_len=1, w=1, **FAST))
PLACES = 36  # the places in use (the end of the last range)


def quick_train(tds, tconf, run_dir, *args, **kw):
    """A stand-in for training (the cache is under test, not training): a run folder as train() leaves it,
    written the same way (``config.json``, ``best.pt``, ``last.pt``, each atomically), with the seeded model."""
    import types

    import torch

    from seqnet.security.files import write_json_atomic
    from seqnet.sequence.checkpoints import save_checkpoint
    from seqnet.sequence.model import SeqNet

    run_dir.mkdir(parents=True)
    write_json_atomic(run_dir / "config.json", tconf.to_dict())
    torch.manual_seed(tconf.seed)
    model = SeqNet(tds.query.dim, 8, tconf.seq_len, tconf.w)
    for name in ("best.pt", "last.pt"):
        save_checkpoint(run_dir / name, model, epoch=1, best_score=0.5)
    return types.SimpleNamespace(out_dir=run_dir, best_epoch=1, best_score=0.5)


def test_a_killed_descriptor_build_never_leaves_a_mixed_cache(tmp_path):
    """D5: the dataset and its flipped train descriptors are one unit (a kill between the two writes used to
    leave the new dataset beside the old flipped descriptors, and the next run used them)."""
    data = shared_data("nordland64")
    a, b = TINY, TINY.replace(describe=TINY.describe.replace(patch=8))
    want = {}
    for name, conf in (("a", a), ("b", b)):
        ds, flip = build_dataset(data, conf, tmp_path / f"fresh-{name}")
        want[name] = (np.array(ds.reference.descriptors), flip)
    assert not np.allclose(want["a"][1], want["b"][1])
    saved, out = tmp_path / "saved", tmp_path / "cache"
    build_dataset(data, a, saved)

    def check():
        if nc.unit(out, "descriptors", key(a)) is not None:  # reused as a whole: a's own
            ds, flip = build_dataset(data, a, out)
            assert np.array_equal(ds.reference.descriptors, want["a"][0]) and np.array_equal(flip, want["a"][1])
        ds, flip = build_dataset(data, b, out)  # the next run: b's, whole (reused or rebuilt)
        assert np.array_equal(ds.reference.descriptors, want["b"][0]) and np.array_equal(flip, want["b"][1])
        assert not [p for p in out.iterdir() if ".seqnet-" in p.name and p.name.endswith(".tmp")]

    def key(conf):
        from seqnet.pipelines.nordland64.data import descriptors_key, list_places

        names = list_places(data)[0][:PLACES]
        return descriptors_key(conf, data, names)

    assert each_crash_point(restorer(saved, out), build_dataset, data, b, out, check=check) > 8


def test_a_killed_or_failed_training_never_leaves_a_mixed_pair(tmp_path, monkeypatch):
    """D4: S_L, S_1 and the PCA are one unit (a kill after models/seqnet.pt, or a failure in S_1's training, used
    to leave the old key beside a new seqnet.pt, and the next run reused the mixed pair)."""
    import seqnet.pipelines.nordland64.models as models_module

    monkeypatch.setattr(models_module, "train", quick_train)
    data = shared_data("nordland64")
    a = TINY
    b = TINY.replace(train={"seed": 1}, train_s1={"seed": 1})
    saved, out = tmp_path / "saved", tmp_path / "cache"
    ds, flipped = build_dataset(data, a, saved)
    train_models(ds, a, saved, flipped)

    def seeds_of(root):
        return {read_checkpoint(root / "models" / f"{r}.pt")["config"]["seed"] for r in ("seqnet", "s1")}

    def check():
        inputs = nc.unit_files(out, "descriptors")
        for conf, seed in ((a, 0), (b, 1)):
            if nc.unit(out, "models", train_key(conf), inputs) is not None:  # reused: one run's pair
                assert seeds_of(out) == {seed}
        models, _ = train_models(ds, b, out, flipped)  # the next run: b's pair, whole
        assert seeds_of(out) == {1} and models["s1"].seq_len == 1
        assert not list((out / "runs" / "seqnet").glob(".*.seqnet-*.tmp"))

    assert each_crash_point(restorer(saved, out), train_models, ds, b, out, flipped, check=check,
                            modes=("after",)) > 8  # the state after rename k is the state before rename k + 1

    restorer(saved, out)()

    def failing(tds, tconf, run_dir, *args, **kw):
        if tconf.seq_len == 1:
            raise RuntimeError("S_1 training failed")
        return quick_train(tds, tconf, run_dir, *args, **kw)

    monkeypatch.setattr(models_module, "train", failing)
    with pytest.raises(RuntimeError, match="S_1 training failed"):
        train_models(ds, b, out, flipped)  # seqnet.pt is b's now, s1.pt still a's
    assert nc.unit(out, "models", train_key(a), nc.unit_files(out, "descriptors")) is None
    assert nc.unit(out, "models", train_key(b), nc.unit_files(out, "descriptors")) is None
    monkeypatch.setattr(models_module, "train", quick_train)
    train_models(ds, a, out, flipped)
    assert seeds_of(out) == {0}


def test_the_real_training_fills_the_cache_and_is_reused(tmp_path):
    data = shared_data("nordland64")
    out = tmp_path / "c"
    ds, flipped = build_dataset(data, TINY, out)
    models, seconds = train_models(ds, TINY, out, flipped)
    (out / "runs" / "seqnet" / ".last.pt.seqnet-dead1.tmp").write_bytes(b"left by a killed run")  # debris
    again, seconds_again = train_models(ds, TINY, out, flipped)
    assert seconds_again == seconds and set(again) == {"seqnet", "s1"}
    seed3 = TINY.replace(train={"seed": 3})
    other, _ = train_models(ds, seed3, out, flipped)  # retrained, debris removed
    assert not list((out / "runs" / "seqnet").glob(".*.tmp")) and read_checkpoint(out / "models" /
                                                                                  "seqnet.pt")["config"]["seed"] == 3
    (out / "runs" / "s1" / "thesis.tex").write_text("precious")  # a file of the user's in the cache's run folder
    for overwrite in (False, True):
        with pytest.raises(OutputError, match="thesis.tex"):
            train_models(ds, TINY.replace(train={"seed": 4}), out, flipped, overwrite=overwrite)
    assert (out / "runs" / "s1" / "thesis.tex").read_text() == "precious"
    assert nc.unit(out, "models", train_key(seed3), nc.unit_files(out, "descriptors"))  # refused before any work


def test_a_changed_cached_file_is_rebuilt_not_reused(tmp_path):
    data = shared_data("nordland64")
    out = tmp_path / "c"
    ds, flipped = build_dataset(data, TINY, out)
    flip = out / "flip_train.npy"
    arr = np.load(flip)
    np.save(flip, arr * 2)  # same size, other values: not the flipped descriptors of this dataset
    _, again = build_dataset(data, TINY, out)
    np.testing.assert_array_equal(again, flipped)


def test_entries_the_cache_did_not_make_are_never_replaced(tmp_path, synth_dataset):
    from seqnet.data.io import save_dataset

    data = shared_data("nordland64")
    out = tmp_path / "c"
    mine = save_dataset(synth_dataset, out / "dataset")  # a user's own seqnet dataset where the cache would be
    before = sorted((p.name, p.read_bytes()) for p in mine.rglob("*") if p.is_file())
    with pytest.raises(OutputError, match="not made by this cache.*--overwrite"):
        build_dataset(data, TINY, out)
    assert sorted((p.name, p.read_bytes()) for p in mine.rglob("*") if p.is_file()) == before
    (out / "runs" / "s1").mkdir(parents=True)
    (out / "runs" / "s1" / "best.pt").write_text("a run of my own")
    with pytest.raises(OutputError, match=r"runs/s1 was not made by this cache"):
        nc.check_owned(out, nc.MODELS)
    ds, _ = build_dataset(data, TINY, out, overwrite=True)  # explicitly: seqnet's dataset replaced
    assert ds.name == "nordland64" and "dataset" in json.loads((out / nc.RECORD).read_text())["owned"]
    (out / nc.RECORD).write_text("my own notes")
    with pytest.raises(OutputError, match="is not a seqnet cache record"):
        build_dataset(data, TINY, out)
