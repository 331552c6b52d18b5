"""Checks of an evaluation that need no descriptors: models present and fitting the descriptors and
L, provenance of reference, query and models, lengths that fit the traverses."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from .data.traverse import Dataset
from .errors import ConfigError
from .methods import Method
from .provenance import check_same
from .sequence_descriptors import SeqNet
from .utils import logger


def check_inputs(ds: Dataset, conf: Any, methods: list[Method], models: Mapping[str, SeqNet]) -> None:
    """Every check that does not need descriptors: models present and fitting, lengths."""
    for m in methods:
        missing = m.models() - set(models)
        if missing:
            need = " and ".join("an S_1 model (--rerank-model CKPT)" if r == "s1" else
                                "an S_L model (--shortlist-model CKPT)" for r in sorted(missing))
            raise ConfigError(f"method {m.name!r} needs {need}")
        if m.min_len() > conf.length:
            raise ConfigError(f"method {m.name!r} uses Delta descriptors, which need seq_len >= {m.min_len()} "
                              f"(got {conf.length}); use a longer --seq-len or other methods")
    check_provenance(ds, conf, models)
    for side, t in (("query", ds.query), ("reference", ds.reference)):
        longest = max(conf.length, conf.match_len)
        if longest > len(t):
            raise ConfigError(f"seq_len={longest} is longer than the {side} traverse of dataset {ds.name!r} "
                              f"({len(t)} frames); use a shorter --seq-len")


def check_provenance(ds: Dataset, conf: Any, models: Mapping[str, SeqNet]) -> None:
    """Reference and query descriptors made alike; each model used on the descriptors (D, provenance)
    and the sequence length it was trained with (unless ``conf.allow_mismatch``)."""
    allow = conf.allow_mismatch
    check_same(ds.reference.provenance, ds.query.provenance, "the reference descriptors", "the query descriptors",
               allow)
    for role, model in models.items():
        name = "S_1" if role == "s1" else f"S_{model.seq_len}"
        if model.in_dims != ds.query.dim:
            raise ConfigError(f"the {role} model ({name}) expects D={model.in_dims} descriptors "
                              f"but the dataset has D={ds.query.dim}")
        check_same(model.provenance, ds.reference.provenance, f"the descriptors the {name} model was trained on",
                   f"the descriptors of dataset {ds.name!r}", allow)
        if role == "seqnet" and model.seq_len != conf.length:
            msg = (f"the S_L model was trained with L={model.seq_len} but is evaluated with L={conf.length}; "
                   f"hint: --seq-len {model.seq_len}, or --allow-mismatch to evaluate it on other windows")
            if not allow:
                raise ConfigError(msg)
            logger.warning("%s (going on as asked)", msg)
