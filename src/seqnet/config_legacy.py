"""TEMPORARY: training defaults as a dict until train/ moves to TrainConfig (removed in this change)."""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any

from .errors import ConfigError

TRAIN_DEFAULTS: dict[str, Any] = {
    "seq_len": 5, "w": 3, "out_dims": None, "window": "centred", "margin": 0.3, "optimizer": "sgd", "lr": 1e-4,
    "momentum": 0.9, "weight_decay": 1e-3, "lr_step": 50, "lr_gamma": 0.5, "batch_size": 16, "epochs": 200,
    "patience": None, "n_negatives": 10, "n_neg_sample": 1000, "cache_refresh": 1000, "pos_radius": None,
    "neg_radius": None, "seed": 0, "device": "auto", "train_split": "train", "val_split": "val",
}


def merge(base: Mapping[str, Any], *overrides: Mapping[str, Any] | None) -> dict[str, Any]:
    """Deep-merge ``overrides`` onto a copy of ``base``; None values are skipped; unknown keys raise."""
    out = copy.deepcopy(dict(base))
    for ov in overrides:
        for key, value in (ov or {}).items():
            if key not in out:
                raise ConfigError(f"unknown configuration key {key!r}; valid: {', '.join(sorted(out))}")
            if value is None:
                continue
            if isinstance(out[key], dict) and isinstance(value, Mapping):
                out[key] = merge(out[key], value)
            else:
                out[key] = copy.deepcopy(value)
    return out
