"""Training SeqNet (S_L, and S_1 with ``seq_len = w = 1``) with a triplet loss and hard negatives.

Queries are windows of the query traverse of the train split, positives/negatives windows of its
reference traverse (see :mod:`seqnet.train.mining`). Each epoch visits every query with a positive
and a negative, in random order; every ``cache_refresh`` queries the descriptors used for mining are
recomputed by the current model (:mod:`seqnet.train.epoch`). After each epoch the model is validated
(Recall@1/5/10/20 on the val split) and the run's files are written (:mod:`seqnet.train.run`).
Settings: :class:`~seqnet.train.config.TrainConfig` (the paper's defaults).

Under torchrun the same code runs in every process (:mod:`seqnet.train.distributed`): rank 0 locks
the run directory, reads the checkpoint to resume, validates and writes the files; the others get
what it read and its val scores, so every rank keeps the same state.

Logging: one INFO line when training starts (with the world size when distributed) and one when it
ends; one DEBUG line per epoch (``seqnet -v``); one progress bar per epoch (:func:`seqnet.core.progress.progress`).
"""

from __future__ import annotations

import contextlib
import time
from pathlib import Path
from typing import TYPE_CHECKING

from ..core.errors import ConfigError, DatasetError
from ..core.lazy import lazy_module
from ..core.log import logger
from ..core.provenance import check_same
from ..data.io import load_dataset
from ..data.sanity import shared_queries
from ..data.traverse import Dataset
from ..methods.checks import accepted_mismatch
from ..methods.trained import descriptor_digests
from ..security.locks import locked
from .config import TrainConfig
from .distributed import World, joined
from .epoch import train_epoch
from .guide import Budget, advice, check_memory, names_pca, plan, plan_text, suggested_pca
from .losses import LOSSES
from .pca_cost import pca_advice
from .record import check_resumed, record_data
from .route import holds_test_queries, split_warnings
from .run import (
    Run,
    check_epochs_left,
    finish_epoch,
    open_files,
    open_run,
    read_resume,
    restored_config,
    run_dataset_path,
    stored_dataset_path,
)
from .rundir import RESTART, check_new, check_resume_target, discard
from .source import TripletSource, named_split, split_windows, triplet_source
from .watch import inactive_epochs, inactive_message, val_warning

torch = lazy_module("torch")

if TYPE_CHECKING:
    from ..sequence.model import SeqNet

VAL_KS = (1, 5, 10, 20)


def validate(model: SeqNet, val_ds: Dataset | None, conf: TrainConfig,
             device: torch.device | None = None) -> dict[str, float]:
    """Recall@1/5/10/20 of ``model`` on the validation split (method "seqnet" for S_L, "s1" for S_1; the
    loss's ``val_method`` over its windows, e.g. ``s1+seqmatch`` for the seqmatch loss) on ``device``
    (default ``conf.device``); ``{}`` without a val split. Leaves the model in training mode."""
    from ..eval.config import EvalConfig
    from ..eval.score import score

    if val_ds is None:
        return {}
    role, dev = model.role, conf.device if device is None else str(device)
    method = LOSSES[conf.loss].val_method or role
    ev_conf = EvalConfig(methods=(method,), seq_len=conf.window_len, window=conf.window, ks=VAL_KS, device=dev)
    ev = score(val_ds, ev_conf, {role: model})
    model.train()
    return {k: float(v) for k, v in ev.results["methods"][method].items() if k.startswith("recall@")}


def prepare(dataset: Dataset, conf: TrainConfig, device: torch.device) -> tuple[TripletSource, Dataset | None]:
    """The training windows on ``device`` and the val split (None: no validation), both checked (windows fit, some
    query has a positive and a negative): everything that can fail on the data fails here, before a run directory."""
    train_ds = named_split(dataset, conf.train_split, "train")
    src = triplet_source(train_ds, conf.window_len, conf.window, conf.mining, device, conf.ref_pad)
    for said in [*split_warnings(train_ds, conf), *holds_test_queries(dataset, conf)]:  # said before training
        logger.warning("%s", said)
    if not conf.validates:
        return src, None
    val_ds = named_split(dataset, conf.val_split, "val")
    split_windows(val_ds, conf.window_len, conf.window, conf.mining, "val", conf.ref_pad)
    if said := shared_queries(dataset, [conf.train_split, conf.val_split]):
        logger.warning("the best epoch is chosen on queries it trains on: %s", said)
    return src, val_ds


def _name(model: SeqNet) -> str:
    return "S_1" if model.role == "s1" else f"S_{model.seq_len}"


def _fit(run: Run, src: TripletSource, val_ds: Dataset | None, device: torch.device,
         budget: Budget | None = None, dataset: Dataset | None = None) -> None:
    """The epochs from the run's next one to ``conf.epochs`` (or early stopping), with the two INFO lines."""
    first, m, world = run.epoch + 1, run.model, run.world
    resumed = f"resuming {run.out_dir} after epoch {run.epoch}: " if run.epoch else ""
    val = f"validating on {val_ds.name}" if val_ds is not None else "no validation"
    left = f" ({src.left_out} more without a positive or a negative left out)" if src.left_out else ""
    procs = f", {world.describe()}, batches of {run.conf.batch_size} split across the ranks" if world.size > 1 else ""
    logger.info("%straining %s (w=%d, D %d->%d) on %d queries%s, %d reference windows, epochs %d..%d, device %s%s, %s",
                resumed, _name(m), m.w, m.in_dims, m.out_dims, src.n_queries, left, len(src.r_idx), first,
                run.conf.epochs, device, procs, val)
    run.record["trained_queries"] = src.n_queries  # the queries trained on (a full window, a positive, a negative)
    run.world.rank0(lambda: _guide(run, src, val_ds, device, budget, dataset))
    t0 = time.perf_counter()
    inactive = _epochs(run, src, val_ds, device, first)
    best = (f"best val R@1 {run.best_score:.4f} at epoch {run.best_epoch}" if val_ds is not None and run.best_epoch
            else "no validation (best.pt = last.pt)")
    early = run.should_stop and run.epoch < run.conf.epochs
    stop = f"; early stop: no better val R@1 for {run.bad_epochs} epochs" if early else ""
    stop += f"; stopped: no active triplet for {inactive_epochs(run.history)} epochs" if inactive else ""
    n = run.epoch - first + 1
    # DEBUG: seqnet train prints the summary (cli/train_cmd.py), once
    logger.debug("trained %s for %d epoch%s (to epoch %d) in %.1f s; %s%s", _name(m), n, "" if n == 1 else "s",
                run.epoch, time.perf_counter() - t0, best, stop)


def _epochs(run: Run, src: TripletSource, val_ds: Dataset | None, device: torch.device, first: int) -> bool:
    """The epochs from ``first`` to ``conf.epochs`` (or a stop); whether they stopped for want of active triplets.
    Interrupted (Ctrl-C), the interruption carries what the run holds and how to continue (``seqnet_hint``, said
    by the CLI): it said only "interrupted"."""
    epoch = first
    try:
        for epoch in range(first, run.conf.epochs + 1):
            t_epoch = time.perf_counter()
            stats = train_epoch(run, src, epoch)
            _end_epoch(run, epoch, stats, val_ds, device, t_epoch)
            inactive = 0 < run.conf.stop_inactive <= inactive_epochs(run.history)
            if inactive:
                said = inactive_message(run.history, run.conf, src.n_queries, run.best_epoch)
                logger.warning("%s", said)
                run.advice.append(said)
            if run.should_stop or inactive:
                return inactive
    except KeyboardInterrupt as e:
        held = (f"{run.out_dir} holds last.pt of epoch {run.epoch} (best.pt: epoch {run.best_epoch or run.epoch}); "
                f"continue with seqnet train --resume {run.out_dir}" if run.epoch else
                f"no epoch was finished; {run.out_dir} can be trained into again")
        e.seqnet_hint = f" during epoch {epoch} of {run.conf.epochs}: {held}"  # type: ignore[attr-defined]
        raise
    return False


def _guide(run: Run, src: TripletSource, val_ds: Dataset | None, device: torch.device,
           budget: Budget | None = None, dataset: Dataset | None = None) -> None:
    """Rank 0, before the first epoch: the training plan (memory, time, checkpoints; ``budget``: the memory
    check's, before the model existed) in one INFO block, then the advice (a PCA it names measured on ``dataset``
    first: :func:`~seqnet.train.pca_cost.pca_advice`) and a val split too small to choose an epoch, one warning
    each (seen from Python without a handler), kept in ``run.advice`` (:mod:`seqnet.train.guide`)."""
    conf = run.conf
    n_val = 0 if val_ds is None else \
        len(split_windows(val_ds, conf.window_len, conf.window, conf.mining, "val", conf.ref_pad).q_idx)
    n_frames = len(src.q_desc) + len(src.r_desc)
    p = plan(conf, run.model.in_dims, src.n_queries, len(src.r_idx), n_frames, n_val, conf.epochs - run.epoch,
             device, len(src.r_desc), len(src.q_desc), budget=budget)
    logger.info("%s", plan_text(p))
    warning = val_warning(n_val, val_ds.name, resumed=run.epoch > 0) if val_ds is not None else None
    measured = pca_advice(dataset, conf, suggested_pca(p), run.dataset_path) if dataset is not None and \
        names_pca(p) else None
    run.advice = [f"advice: {a}" for a in advice(p, measured)] + [warning] * bool(warning)
    for said in run.advice:
        logger.warning("%s", said)


def _end_epoch(run: Run, epoch: int, stats: dict[str, float], val_ds: Dataset | None, device: torch.device,
               t_epoch: float) -> None:
    """Validation and the run's files on rank 0; then, with rank 0's val scores, the same bookkeeping
    (schedule, best, patience: the early-stopping decision) on the other ranks."""

    def on_rank0() -> dict[str, float]:
        metrics = validate(run.model, val_ds, run.conf, device)
        finish_epoch(run, epoch, stats, metrics, time.perf_counter() - t_epoch)
        return metrics

    metrics = run.world.rank0(on_rank0)
    if not run.world.is_rank0:
        finish_epoch(run, epoch, stats, metrics, time.perf_counter() - t_epoch)


def train(dataset: Dataset, conf: TrainConfig | None, out_dir: str | Path, resume: bool | str | Path = False,
          dataset_path: str | Path | None = None, allow_mismatch: bool = False) -> Run:
    """Train a SeqNet model on ``dataset``'s train split, validating on its val split.

    Args:
        dataset: the whole dataset (splits named by ``conf.train_split`` / ``conf.val_split``).
        conf: settings (None: the defaults; when resuming, the run's). Dataset-dependent defaults are
            resolved here (:meth:`TrainConfig.resolve`). When resuming, ``conf`` must equal the run's
            configuration (:func:`seqnet.train.run.resume_config`) except for epochs, patience and
            device, else :class:`ConfigError`.
        out_dir: run directory (``last.pt``, ``best.pt``, ``config.json``, TensorBoard events); a new
            run needs it absent or empty.
        resume: continue the run in ``out_dir`` (True), or the run in this directory / checkpoint.
        dataset_path: recorded in the run so that resuming finds the data (default when resuming: the run's).
        allow_mismatch: train even when reference and query descriptors were made differently (provenance).

    Under torchrun (``WORLD_SIZE`` > 1) every process calls this; rank 0 alone locks and writes
    ``out_dir`` (:mod:`seqnet.train.distributed`).

    Returns:
        The finished :class:`Run` (model, history, best score and epoch).
    """
    if not isinstance(dataset, Dataset):
        raise ConfigError(f"train() needs a seqnet Dataset, got {type(dataset).__name__} (hint: load_dataset(DIR))")
    if conf is not None and not isinstance(conf, TrainConfig):
        raise ConfigError(f"train() needs a TrainConfig, got {type(conf).__name__} "
                          "(hint: TrainConfig(epochs=...) or TrainConfig.from_dict({...}))")
    out_dir = Path(out_dir)
    check_resume_target(resume, out_dir)
    check_same(dataset.reference.provenance, dataset.query.provenance, "the reference descriptors",
               "the query descriptors", allow_mismatch or accepted_mismatch(dataset))
    with joined() as world, contextlib.ExitStack() as held:
        conf, payload, path, budget = world.rank0(lambda: _claim(held, dataset, conf, out_dir, resume, dataset_path,
                                                         allow_mismatch))
        run, src, val_ds, device = world.agree(lambda: _start(dataset, conf, out_dir, payload, path, world))
        run.net = world.wrap(run.model)  # DistributedDataParallel when distributed
        world.rank0(lambda: open_files(run))
        done = False
        try:
            _fit(run, src, val_ds, device, budget, dataset)
            done = True
        finally:
            run.close(failed=not done)
            run.net = None
    return run


def _claim(held: contextlib.ExitStack, dataset: Dataset, conf: TrainConfig | None, out_dir: Path,
           resume: bool | str | Path, dataset_path: str | Path | None,
           allow_mismatch: bool = False) -> tuple[TrainConfig, dict | None, str | None, Budget]:
    """Rank 0: lock ``out_dir`` (a second writer of this run is refused), read the checkpoint to resume
    (its descriptors' provenance checked against the dataset's: a rebuilt dataset is refused unless
    ``allow_mismatch``) or check that the directory is free, and refuse a run over the memory available; the
    run's configuration, checkpoint, dataset path and the memory checked (the plan's)."""
    held.enter_context(locked(out_dir))
    payload = None
    if resume:
        payload = read_resume(out_dir if resume is True else Path(resume))
        conf = restored_config(payload, conf)  # then its descriptors and splits, those of the dataset now
        check_resumed(payload, dataset, dataset_path, out_dir, conf, allow_mismatch)
        check_epochs_left(payload.get("epoch"), conf.epochs, out_dir)
        dataset_path = dataset_path or stored_dataset_path(payload)
        if RESTART in payload:  # no last.pt: nothing to resume, the run starts again with its configuration
            discard(out_dir, payload[RESTART], "starting it again from epoch 1 with its stored configuration")
            payload = None
    else:
        conf = (conf or TrainConfig()).resolve(dataset)
        check_new(out_dir)
    budget = check_memory(conf, dataset)
    return conf, payload, str(dataset_path) if dataset_path is not None else None, budget


def _start(dataset: Dataset, conf: TrainConfig, out_dir: Path, payload: dict | None, dataset_path: str | None,
           world: World) -> tuple[Run, TripletSource, Dataset | None, torch.device]:
    """Every rank: its device, the checked training data and the run's state (no file written)."""
    device = world.device(conf.device)
    src, val_ds = prepare(dataset, conf, device)
    run = open_run(conf, src.n_queries, dataset.query.dim, device, out_dir, payload, dataset_path, files=False,
                   n_refs=len(src.r_idx))
    run.world = world
    record_data(run, dataset)  # checkpoints record what the model reads and its val queries
    run.dataset_digests = descriptor_digests(dataset_path) if world.is_rank0 else None
    return run, src, val_ds, device


def main(conf: TrainConfig | None, dataset: str | Path | None, out: str | Path | None,
         resume: str | Path | None = None, allow_mismatch: bool = False) -> Path:
    """hloc-style stage: train on the dataset directory ``dataset`` into the run directory ``out``
    (or continue the run ``resume``: a directory or its ``last.pt``; ``out`` defaults to it, the
    dataset to the one the run recorded). Returns the run directory."""
    if out is None and resume is not None:
        out = Path(resume).parent if Path(resume).is_file() else resume
    if out is None:
        raise ConfigError("no run directory: give --out RUN (or --resume RUN)")
    path = dataset if dataset is not None or resume is None else run_dataset_path(resume)
    if path is None:
        raise ConfigError("no dataset: give --dataset DIR")
    try:
        data = load_dataset(path)
    except DatasetError as e:
        if dataset is not None:
            raise
        raise DatasetError(f"{e} (the dataset the run in {resume} recorded; hint: --dataset DIR if it moved)") from e
    run = train(data, conf, out, resume=resume or False, dataset_path=Path(path).resolve(),
                allow_mismatch=allow_mismatch)
    return run.out_dir

