"""TrainConfig: the paper's defaults, validation with one-line errors, round trips, dataset defaults."""

from __future__ import annotations

import dataclasses
import json

import pytest
import torch

from seqnet.core.errors import ConfigError
from seqnet.train.config import OPTIMIZERS, MiningConfig, TrainConfig

PAPER = {"seq_len": 5, "w": 3, "out_dims": None, "window": "centred", "margin": 0.3, "optimizer": "sgd", "lr": 1e-4,
         "momentum": 0.9, "weight_decay": 1e-3, "lr_step": 50, "lr_gamma": 0.5, "batch_size": 16, "epochs": 200,
         "patience": None, "stop_inactive": 5, "n_negatives": 10, "n_neg_sample": 1000, "cache_refresh": 1000,
         "pos_radius": None, "neg_radius": None, "seed": 0, "device": "auto", "train_split": "train",
         "val_split": "val", "loss": "triplet", "match_len": 5, "speed_augment": None}


def test_defaults_are_the_papers():
    assert TrainConfig().to_dict() == PAPER  # the same keys, in the same order, with the same values


def test_from_dict_to_dict_round_trip():
    conf = TrainConfig(seq_len=4, w=2, out_dims=32, optimizer="adam", patience=3, pos_radius=2.0, neg_radius=9.0,
                       val_split="none", seed=7)
    data = json.loads(json.dumps(conf.to_dict()))
    assert TrainConfig.from_dict(data) == conf
    assert TrainConfig.from_dict({}) == TrainConfig()
    assert TrainConfig(optimizer="Adam").optimizer == "adam"
    assert TrainConfig(lr=1).lr == 1.0 and isinstance(TrainConfig(lr=1).lr, float)


def test_unknown_key_names_the_valid_ones():
    with pytest.raises(ConfigError, match="unknown TrainConfig key 'nonsense'; valid: seq_len, w, "):
        TrainConfig.from_dict({"nonsense": 1})


BAD = [("lr", 0), ("lr", -1e-3), ("margin", 0.0), ("lr_gamma", 0), ("momentum", -0.1), ("weight_decay", -1e-3),
       ("seed", -1), ("batch_size", 0), ("epochs", 0), ("n_negatives", 0), ("n_neg_sample", 0), ("lr_step", 0),
       ("cache_refresh", -1), ("patience", 0), ("out_dims", 0), ("seq_len", 0), ("w", 0), ("w", 6),
       ("optimizer", "rmsprop"), ("window", "middle"), ("pos_radius", 0.0), ("neg_radius", -1.0),
       ("device", "tpu"), ("batch_size", 1.5), ("batch_size", True), ("lr", "fast"), ("lr", float("nan")),
       ("train_split", ""), ("epochs", "10"), ("loss", "contrastive"), ("match_len", 0), ("speed_augment", [2, 1]),
       ("speed_augment", [0, 1]), ("speed_augment", "fast"), ("speed_augment", [1, float("inf")])]


@pytest.mark.parametrize(("key", "value"), BAD, ids=[f"{k}={v!r}" for k, v in BAD])
def test_bad_values_raise_one_line_config_error_naming_the_key(key, value):
    with pytest.raises(ConfigError, match=key) as info:
        TrainConfig.from_dict({key: value})
    assert "\n" not in str(info.value)


def test_radii_order_and_w_range():
    with pytest.raises(ConfigError, match="pos_radius <= neg_radius"):
        TrainConfig(pos_radius=30.0, neg_radius=20.0)
    with pytest.raises(ConfigError, match="w must be an integer in 1..3"):
        TrainConfig(seq_len=3, w=4)
    assert TrainConfig(seq_len=1, w=1).w == 1
    with pytest.raises(ConfigError, match="lr"):
        TrainConfig().replace(lr=-1.0)  # replace validates again


def test_resolve_fills_dataset_dependent_defaults(synth_dataset):
    conf = TrainConfig().resolve(synth_dataset)
    assert (conf.pos_radius, conf.neg_radius) == (5.0, 20.0)  # dataset.extra
    assert conf.out_dims == synth_dataset.query.dim
    assert conf.merge(out_dims=None) == conf  # None keeps
    assert conf.replace(out_dims=None).out_dims is None  # None is a value
    bare = dataclasses.replace(synth_dataset, extra={}, radius=3.0)
    assert (TrainConfig().resolve(bare).pos_radius, TrainConfig().resolve(bare).neg_radius) == (3.0, 12.0)
    assert TrainConfig(pos_radius=2.0).resolve(bare).neg_radius == 8.0
    assert TrainConfig(out_dims=4, pos_radius=1.0, neg_radius=2.0).resolve(synth_dataset).to_dict() == \
        {**PAPER, "out_dims": 4, "pos_radius": 1.0, "neg_radius": 2.0}
    with pytest.raises(ConfigError, match="pos_radius <= neg_radius"):
        TrainConfig(pos_radius=30.0).resolve(synth_dataset)  # the dataset's neg_radius is 20


def test_mining_settings():
    conf = TrainConfig(pos_radius=2.0, neg_radius=8.0, n_negatives=3, n_neg_sample=40, margin=0.1, cache_refresh=0)
    assert conf.mining == MiningConfig(2.0, 8.0, 3, 40, 0.1, 0)
    with pytest.raises(ConfigError, match="not resolved"):
        _ = TrainConfig().mining


def test_resumed_allows_only_epochs_patience_device():
    run = TrainConfig(seq_len=3, w=2, out_dims=8, pos_radius=5.0, neg_radius=20.0, patience=2)
    assert run.resumed(None) == run
    later = run.resumed(run.replace(epochs=300, device="cpu"))
    assert (later.epochs, later.device, later.patience) == (300, "cpu", 2)
    assert run.resumed(dataclasses.replace(run, patience=None)).patience is None
    with pytest.raises(ConfigError, match="cannot change 'seq_len' when resuming .*only epochs, patience, device"):
        run.resumed(run.replace(seq_len=5))


def test_optimizers_table():
    params = [torch.nn.Parameter(torch.zeros(2))]
    sgd = OPTIMIZERS["sgd"](params, TrainConfig())
    assert isinstance(sgd, torch.optim.SGD)
    assert sgd.defaults["momentum"] == 0.9 and sgd.defaults["weight_decay"] == 1e-3 and sgd.defaults["lr"] == 1e-4
    adam = OPTIMIZERS["adam"](params, TrainConfig(optimizer="adam", lr=1e-3, weight_decay=0.0))
    assert isinstance(adam, torch.optim.Adam) and adam.defaults["lr"] == 1e-3


def test_loss_table_settings():
    conf = TrainConfig(seq_len=1, w=1, loss="seqmatch", match_len=4, speed_augment=[0.5, 2])
    assert conf.window_len == 4 and conf.speed_augment == (0.5, 2.0)
    assert TrainConfig.from_dict(json.loads(json.dumps(conf.to_dict()))) == conf
    assert TrainConfig(seq_len=5, w=3, match_len=4).window_len == 5  # the triplet loss: S_L's own window
    with pytest.raises(ConfigError, match=r"the seqmatch loss trains S_1 \(seq_len = w = 1\), got seq_len=5, w=3 "
                                          r"\(hint: --seq-len 1 --w 1 --loss seqmatch") as info:
        TrainConfig(loss="seqmatch")
    assert "\n" not in str(info.value)
    with pytest.raises(ConfigError, match="unknown loss 'seqmatchnet'; valid: triplet, seqmatch"):
        TrainConfig(seq_len=1, w=1, loss="seqmatchnet")
