"""Defaults in one place, named presets as data, and override merging.

Every command resolves its configuration as ``merge(DEFAULTS, preset, user overrides)`` and writes
the result beside its outputs (``config.json`` or the ``"config"`` key of a results file).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any

from .errors import ConfigError

EVAL_DEFAULTS: dict[str, Any] = {
    "methods": ["single", "smoothing", "delta", "raw+seqmatch", "delta+seqmatch", "hvpr"],
    "seq_len": 5,  # L: window length of sequence descriptors and of SeqMatch
    "window": "centred",  # "centred" (paper) or "causal" (online)
    "radius": None,  # None: the dataset's localisation radius
    "extra_radii": [],
    "ks": [1, 5, 10, 20, 100],
    "top_k": 20,  # HVPR shortlist size
    "shortlist": None,  # HVPR shortlister; None: "seqnet" with a model, else "delta"
    "rerank": None,  # HVPR re-ranking descriptor; None: "s1" with a model, else "raw"
    "split": "test",  # used when the dataset defines it, else the whole dataset
    "backend": "torch",  # k-NN: "torch" or "faiss"
    "device": "auto",
}

# Paper defaults (SeqNet supplementary): margin 0.3, SGD lr 1e-4, momentum 0.9, wd 1e-3,
# lr x0.5 every 50 epochs, batch 16 queries, 10 hard negatives from 1000 sampled.
TRAIN_DEFAULTS: dict[str, Any] = {
    "seq_len": 5,
    "w": 3,
    "out_dims": None,  # None: same as the input dimension
    "window": "centred",
    "margin": 0.3,
    "optimizer": "sgd",
    "lr": 1e-4,
    "momentum": 0.9,
    "weight_decay": 1e-3,
    "lr_step": 50,
    "lr_gamma": 0.5,
    "batch_size": 16,
    "epochs": 200,
    "patience": None,
    "n_negatives": 10,
    "n_neg_sample": 1000,
    "cache_refresh": 1000,  # queries between refreshes of the mining cache
    "pos_radius": None,  # None: the dataset's / preset's value
    "neg_radius": None,
    "seed": 0,
    "device": "auto",
    "train_split": "train",
    "val_split": "val",
}

SYNTH_DEFAULTS: dict[str, Any] = {
    "places": 600,
    "dim": 64,
    "seed": 0,
    "noise": 1.5,  # independent per-frame noise (relative to the place signal)
    "nuisance": 1.0,  # slowly varying, condition-specific appearance change in a few directions
}


def merge(base: Mapping[str, Any], *overrides: Mapping[str, Any] | None) -> dict[str, Any]:
    """Deep-merge ``overrides`` onto a copy of ``base``; ``None`` values in overrides are skipped.

    Raises :class:`ConfigError` for keys that ``base`` does not define.
    """
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
