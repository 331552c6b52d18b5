"""What a run's checkpoints record of the data it trains on, and the checks that a resumed run trains on the same
data: the queries and references of its train and val splits (eval holds a model to its training queries wherever
the same descriptors are read: :mod:`seqnet.methods.trained`), and, on ``--resume``, the descriptors
(:func:`seqnet.train.state.check_descriptors`, :func:`seqnet.train.state.check_digests`) and these split ranges
(:func:`check_splits`: a dataset rebuilt with new splits would train and choose the epoch on other queries)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..core.errors import ConfigError
from ..data.traverse import Dataset
from ..methods.trained import descriptor_digests, names_digest
from .config import TrainConfig
from .state import check_descriptors, check_digests

if TYPE_CHECKING:
    from .run import Run

RANGES = ("train_queries", "train_references", "val_queries", "val_references")


def data_record(dataset: Dataset, conf: TrainConfig) -> dict[str, Any]:
    """``{"train_queries": [a, b], "train_references": [c, d], "val_queries", "val_references" (None without
    validation), "query_names": "N:HASH" (None without names)}`` of ``dataset`` split as ``conf`` says."""
    out: dict[str, Any] = {}
    for what, split in (("train", conf.train_split), ("val", conf.val_split if conf.validates else None)):
        rng = dataset.ranges(split) if split is not None else None
        for side, key in (("query", "queries"), ("reference", "references")):
            out[f"{what}_{key}"] = [int(v) for v in rng[side]] if rng else None
    out["query_names"] = names_digest(dataset.query.names)
    return out


def record_data(run: Run, dataset: Dataset) -> None:
    """What the run's checkpoints record of ``dataset``: its descriptors' provenance (what the model reads) and
    :func:`data_record` (the queries the model trains on and its best epoch is chosen on: eval warns on them, the
    checkpoint alone)."""
    run.model.provenance = dataset.reference.provenance
    run.record = data_record(dataset, run.conf)


def _shown(rng: Any) -> str:
    return f"{rng[0]}:{rng[1]}" if isinstance(rng, list | tuple) and len(rng) == 2 else "none"


def check_splits(payload: Mapping[str, Any], dataset: Dataset, conf: TrainConfig, run: Path) -> None:
    """The run in ``run`` (its ``last.pt``, ``payload``) resumed on ``dataset`` split as its configuration ``conf``
    says: a :class:`ConfigError` (one line) naming each range that differs from those the run recorded (a dataset
    rebuilt with new ``--split``: the run would train and choose its epoch on other queries, and compare val R@1
    across two val splits). Ranges a checkpoint did not record (older runs) are not checked, nor data of another D
    (the architecture check says the checkpoint does not fit)."""
    model = payload.get("model")
    if not isinstance(model, Mapping) or model.get("in_dims") != dataset.query.dim:
        return
    now = data_record(dataset, conf)
    changed = [(k, payload[k], now[k]) for k in RANGES if k in payload and payload[k] != now[k]
               and (payload[k] is None or isinstance(payload[k], list | tuple))]
    if not changed:
        return
    said = ", ".join(f"{k.replace('_', ' ')} {_shown(a)} -> {_shown(b)}" for k, a, b in changed)
    n_refs = len(dataset.reference)
    old = [f"--split {name}={_spec(payload, name, n_refs)}" for name, split in (("train", conf.train_split),
                                                                               ("val", conf.val_split))
           if split == name and isinstance(payload.get(f"{name}_queries"), list | tuple)]
    rebuild = f", or rebuild {dataset.name!r} with the run's splits ({' '.join(old)})" if old else ""
    raise ConfigError(f"the splits of dataset {dataset.name!r} changed since the run in {run} started ({said}): "
                      "resuming would train and choose its epoch on other queries (hint: start a new run, "
                      f"seqnet train --out NEW{rebuild})")


def _spec(payload: Mapping[str, Any], name: str, n_refs: int) -> str:
    """``A:B`` (queries against the whole reference of ``n_refs`` frames) or ``A:B,C:D`` (references, queries) of
    split ``name`` as the run recorded it."""
    q, r = payload.get(f"{name}_queries"), payload.get(f"{name}_references")
    whole = not isinstance(r, list | tuple) or list(r) == [0, n_refs]
    return _shown(q) if whole else f"{_shown(r)},{_shown(q)}"


def check_resumed(payload: Mapping[str, Any], dataset: Dataset, dataset_path: str | Path | None, run: Path,
                  conf: TrainConfig, allow_mismatch: bool = False) -> None:
    """Everything a resumed run checks of the dataset before any epoch: descriptors made alike (provenance; the
    recorded hashes of the dataset directory ``dataset_path``: ``allow_mismatch`` makes either a warning) and the
    train and val ranges the run recorded (:func:`check_splits`)."""
    check_descriptors(payload, dataset.reference.provenance, dataset.query.dim, run, dataset.name, allow_mismatch)
    if dataset_path is not None:  # the dataset given is that directory's: its recorded hashes
        check_digests(payload, descriptor_digests(dataset_path), run, dataset.name, allow_mismatch)
    check_splits(payload, dataset, conf, run)
