"""Restoring a run from its ``last.pt``: every part of the stored training state is checked against the run
it is restored into before it is used, so a crafted, foreign or damaged file is one :class:`CheckpointError`
(exit 2), never a traceback later in training (an out-of-range negative index, an optimiser buffer of
another shape, a scheduler attribute overwritten).

Checked: the architecture against the weights (:func:`seqnet.sequence.checkpoints.check_architecture`, in
:func:`seqnet.train.run.read_resume`), the weights finite, the optimiser's settings and buffers (the fresh
optimiser's types and the parameters' shapes), the scheduler's keys and types, the generator state (size and
dtype), the negative cache (shape, integer dtype, indices of reference windows or -1), the counters and the
history; and, before any of it (:func:`check_descriptors`, :func:`check_digests`), that the dataset's
descriptors are made as those the run was trained on and, where seqnet recorded their hashes, are those files.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ..core.errors import CheckpointError
from ..core.lazy import lazy_module
from ..core.log import logger
from ..core.provenance import ProvenanceError, check_same
from ..security.limits import INDEX_MAX, number

torch = lazy_module("torch")

Run = Any  # seqnet.train.run.Run (not imported: run imports this module)

TRAIN_STATE = ("optimizer", "scheduler", "neg_cache", "rng", "best_epoch", "bad_epochs", "history")


def _short(x: object) -> str:
    text = repr(x) if not isinstance(x, torch.Tensor) else f"tensor{tuple(x.shape)} {x.dtype}"
    return text if len(text) <= 60 else text[:57] + "..."


def _like(fresh: Any, stored: Any) -> bool:
    """Whether ``stored`` (from the file) has the kind of value ``fresh`` (this run's own) has."""
    if fresh is None or isinstance(fresh, bool):
        return stored is None or isinstance(stored, bool)
    if isinstance(fresh, (int, float)):
        return isinstance(stored, (int, float)) and not isinstance(stored, bool) and math.isfinite(stored)
    if isinstance(fresh, (tuple, list)):
        return isinstance(stored, (tuple, list)) and len(stored) == len(fresh) and \
            all(_like(a, b) for a, b in zip(fresh, stored, strict=True))
    if isinstance(fresh, torch.Tensor):
        return isinstance(stored, torch.Tensor) and stored.shape == fresh.shape and stored.dtype == fresh.dtype
    return type(stored) is type(fresh)


def _check_optimizer(run: Run, fresh_groups: list[dict[str, Any]], path: Path) -> None:
    for fresh, group in zip(fresh_groups, run.optimizer.param_groups, strict=True):
        for key, value in fresh.items():
            if key != "params" and key in group and not _like(value, group[key]):
                raise CheckpointError(f"{path}: optimiser setting {key!r} is {_short(group[key])}, not a value like "
                                      f"{_short(value)}")
    for p in run.model.parameters():
        for key, value in run.optimizer.state.get(p, {}).items():
            ok = value is None or (isinstance(value, torch.Tensor) and value.is_floating_point() and
                                   (value.ndim == 0 or value.shape == p.shape)) or _like(0.0, value)
            if not ok:
                raise CheckpointError(f"{path}: optimiser buffer {key!r} is {_short(value)}, not a "
                                      f"{tuple(p.shape)} float tensor of the weights")


def _load_scheduler(run: Run, stored: Any, path: Path) -> None:
    fresh = run.scheduler.state_dict()
    if not isinstance(stored, Mapping):
        raise CheckpointError(f"{path}: the scheduler state is {_short(stored)}, not a mapping")
    for key, value in stored.items():
        if key not in fresh and key != "verbose":
            raise CheckpointError(f"{path}: unknown scheduler state {str(key)[:40]!r}")
        if key in fresh and not _like(fresh[key], value):
            raise CheckpointError(f"{path}: scheduler state {key!r} is {_short(value)}, not like {_short(fresh[key])}")
    run.scheduler.load_state_dict({k: v for k, v in stored.items() if k in fresh})


def _check_cache(cache: Any, shape: tuple[int, ...], n_refs: int | None, path: Path) -> None:
    if not isinstance(cache, torch.Tensor) or cache.dtype != torch.long:
        raise CheckpointError(f"{path}: the negative cache is {_short(cache)}, not an int64 tensor")
    if tuple(cache.shape) != shape:
        raise CheckpointError(f"the checkpoint does not fit this dataset: {path} has a negative cache of "
                              f"{tuple(cache.shape)[0] if cache.ndim else 0} training queries, this dataset gives "
                              f"{shape[0]} (hint: resume with the dataset the run was trained on)")
    if cache.numel() and (int(cache.min()) < -1 or (n_refs is not None and int(cache.max()) >= n_refs)):
        raise CheckpointError(f"{path}: the negative cache holds indices outside the {n_refs} reference windows "
                              "(hint: resume with the dataset the run was trained on)")


def _counters(payload: Mapping[str, Any], st: Mapping[str, Any], path: Path) -> tuple[int, float, int, int]:
    epoch = int(number(payload["epoch"], f"{path}: epoch", 1, INDEX_MAX, CheckpointError))
    best = payload["best_score"]
    if isinstance(best, bool) or not isinstance(best, (int, float)):
        raise CheckpointError(f"{path}: best_score must be a number, got {_short(best)}")
    best_epoch = int(number(st["best_epoch"], f"{path}: best_epoch", 0, epoch, CheckpointError))
    bad = int(number(st["bad_epochs"], f"{path}: bad_epochs", 0, epoch, CheckpointError))
    history = st["history"]
    if not isinstance(history, list) or not all(isinstance(h, Mapping) for h in history):
        raise CheckpointError(f"{path}: the history must be a list of per-epoch records, got {_short(history)}")
    return epoch, float(best), best_epoch, bad


def check_descriptors(payload: Mapping[str, Any], provenance: dict | None, dim: int, run: Path, dataset: str,
                      allow: bool = False) -> None:
    """The run in ``run`` (its ``last.pt``, ``payload``) resumed on the descriptors of the dataset named
    ``dataset``, of ``dim`` made as ``provenance``:
    a :class:`~seqnet.core.provenance.ProvenanceError` naming the difference when the run's descriptors were
    made otherwise (a dataset rebuilt since; ``allow``: a warning); descriptors of another D, a
    :class:`CheckpointError` saying so first (another dataset, or another PCA of it: the provenance said "the dataset
    was rebuilt since", and after --allow-mismatch the architecture check "the checkpoint does not fit")."""
    model = payload.get("model")
    was = model.get("in_dims") if isinstance(model, Mapping) else None
    if type(was) is int and was != dim:
        where = f" ({payload['dataset_path']})" if isinstance(payload.get("dataset_path"), str) else ""
        raise CheckpointError(f"the run in {run} trained on D={was} descriptors and dataset {dataset!r} has D={dim}: "
                              "another dataset, or another PCA of it, which the checkpoint does not fit; hint: resume "
                              f"on the dataset the run trained on{where}, or start a new run (--out)")
    if was == dim:
        check_same(payload.get("provenance"), provenance, f"the descriptors the run in {run} was trained on",
                   f"the descriptors of dataset {dataset!r}", allow)


def check_digests(payload: Mapping[str, Any], now: Mapping[str, str] | None, run: Path, dataset: str,
                  allow: bool = False) -> None:
    """The run in ``run`` (its ``last.pt``, ``payload``, recording ``dataset_digests``) resumed on dataset
    ``dataset`` whose descriptor files hash to ``now`` (:func:`seqnet.methods.trained.descriptor_digests`): a
    :class:`~seqnet.core.provenance.ProvenanceError` naming the files that changed (``allow``: a warning);
    nothing is checked when either side recorded no hashes."""
    then = payload.get("dataset_digests")
    if not isinstance(then, Mapping) or not now:
        return
    changed = sorted(str(k) for k in set(then) | set(now) if then.get(k) != now.get(k))
    if not changed:
        return
    msg = (f"the descriptors of dataset {dataset!r} are not those the run in {run} was trained on "
           f"({', '.join(changed[:3])} changed: the dataset was rebuilt since)")
    if allow:
        logger.warning("%s; going on as asked (--allow-mismatch)", msg)
        return
    raise ProvenanceError(f"{msg}; hint: resume on the dataset the run was trained on, or start a new run "
                          "(--allow-mismatch if you know they are comparable)")


def check_state(payload: Mapping[str, Any], path: Path) -> Mapping[str, Any]:
    """The ``train_state`` of a ``last.pt`` with every entry resuming needs (else one line naming them)."""
    st = payload.get("train_state")
    missing = [k for k in TRAIN_STATE if not isinstance(st, Mapping) or k not in st]
    missing += [k for k in ("state_dict", "model", "epoch", "best_score") if k not in payload]
    if missing or not isinstance(st.get("neg_cache"), torch.Tensor) or not isinstance(st.get("rng"), Mapping):
        what = ", ".join(missing) or "a negative cache tensor and random state"
        raise CheckpointError(f"{path} lacks what resuming needs ({what}); it was not written by a seqnet training "
                              "run of this version (hint: start a new run)")
    return st


def restore(run: Run, payload: Mapping[str, Any], n_refs: int | None = None) -> None:
    """Put the state stored in ``payload`` (a checked ``last.pt``) into the fresh ``run``; ``n_refs``: the
    number of training reference windows (the negative cache's index range)."""
    path = run.out_dir / "last.pt"
    st = check_state(payload, path)
    if payload["model"] != run.model.config():
        raise CheckpointError(f"the checkpoint does not fit this dataset: model {str(payload['model'])[:120]}, now "
                              f"{run.model.config()} (hint: resume with the dataset the run was trained on)")
    _check_cache(st["neg_cache"], tuple(run.neg_cache.shape), n_refs, path)
    counters = _counters(payload, st, path)
    gen = st["rng"].get("generator")
    if not _like(run.generator.get_state(), gen):
        raise CheckpointError(f"{path}: the generator state is {_short(gen)}, not a torch generator's")
    fresh_groups = [dict(g) for g in run.optimizer.param_groups]
    try:
        run.model.load_state_dict(payload["state_dict"])
        run.optimizer.load_state_dict(st["optimizer"])
        _check_optimizer(run, fresh_groups, path)
        _load_scheduler(run, st["scheduler"], path)
        run.generator.set_state(gen)
    except (RuntimeError, ValueError, KeyError, TypeError, IndexError, AttributeError) as e:
        raise CheckpointError(f"{path}: the stored training state does not fit the run "
                              f"({' '.join(str(e).split())[:200]})") from e
    if not all(bool(torch.isfinite(p).all()) for p in run.model.parameters()):
        raise CheckpointError(f"{path}: the weights hold NaN or inf (a diverged or damaged run); hint: start again")
    run.neg_cache.copy_(st["neg_cache"])
    run.epoch, run.best_score, run.best_epoch, run.bad_epochs = counters
    run.history = list(st["history"])
