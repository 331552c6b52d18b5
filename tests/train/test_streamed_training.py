"""Training on a streamed reference with a spilled mining cache gives the in-memory run's numbers exactly."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from seqnet.core.memmaps import Spilled
from seqnet.data.io import load_dataset
from seqnet.sequence.checkpoints import read_checkpoint
from seqnet.train import TrainConfig, mining, train
from seqnet.train.mining import compute_cache
from seqnet.train.source import triplet_source

FAST = TrainConfig(optimizer="adam", lr=1e-2, batch_size=16, cache_refresh=40, n_neg_sample=50, seq_len=3, w=2,
                   out_dims=8, device="cpu", epochs=2)
S1_SEQMATCH = FAST.replace(seq_len=1, w=1, loss="seqmatch", match_len=3)


def _run(synth_dir, conf, out):
    train(load_dataset(synth_dir), conf, out)
    return read_checkpoint(out / "last.pt")


@pytest.mark.parametrize("conf", [FAST, S1_SEQMATCH, S1_SEQMATCH.replace(loss="vseqmatch"),
                                  S1_SEQMATCH.replace(loss="graph")], ids=["triplet", "seqmatch", "vseqmatch", "graph"])
def test_spilled_mining_cache_and_streamed_reference_train_the_same_weights(synth_dir, tmp_path, monkeypatch, conf):
    monkeypatch.setattr(mining, "COL_BLOCK_BYTES", 7 * 8 * 4)  # distances in column blocks of 7 (framewise: 2) windows
    held = _run(synth_dir, conf, tmp_path / "held")
    monkeypatch.setenv("SEQNET_SPILL_MB", "0")  # the reference mining cache goes to a spill file
    monkeypatch.setenv("SEQNET_RESIDENT_MB", "0")  # the dataset's descriptors stay memory maps, read in blocks
    spilled = _run(synth_dir, conf, tmp_path / "spilled")
    for key, value in held["state_dict"].items():
        assert torch.equal(value, spilled["state_dict"][key]), key
    assert torch.equal(held["train_state"]["neg_cache"], spilled["train_state"]["neg_cache"])
    assert (held["train_state"]["neg_cache"] >= 0).any()  # negatives were mined (the comparison can fail)


def test_the_reference_cache_spills_and_reads_back_the_held_numbers(synth_dir, monkeypatch):
    conf = FAST.resolve(load_dataset(synth_dir))
    model = torch.nn.Sequential(torch.nn.Flatten(), torch.nn.Linear(3 * 16, 8))
    src = triplet_source(load_dataset(synth_dir).split("train"), 3, "centred", conf.mining, torch.device("cpu"))
    q, held = compute_cache(model, src, torch.arange(5), spill=True)
    assert isinstance(held.feats, torch.Tensor)  # small: held
    monkeypatch.setenv("SEQNET_SPILL_MB", "0")
    monkeypatch.setenv("SEQNET_RESIDENT_MB", "0")
    src = triplet_source(load_dataset(synth_dir).split("train"), 3, "centred", conf.mining, torch.device("cpu"))
    assert isinstance(src.r_desc, np.memmap)  # the reference is not copied into a tensor
    q2, spilled = compute_cache(model, src, torch.arange(5), spill=True)
    assert isinstance(spilled.feats, Spilled)
    assert torch.equal(q, q2) and torch.equal(held.whole(torch.device("cpu")), spilled.whole(torch.device("cpu")))
    monkeypatch.setattr(mining, "COL_BLOCK_BYTES", 5 * 8 * 4)  # column blocks of 5 windows, held or spilled alike
    d_held = mining.cache_distances(mining.pairwise_distances, q, held)
    assert d_held.shape == (5, len(src.r_idx))
    assert torch.equal(mining.cache_distances(mining.pairwise_distances, q, spilled), d_held)
