"""A training run and its directory: state, opening (fresh or from ``RUN/last.pt``) and the files
written after every epoch.

``RUN/config.json``: the resolved :class:`TrainConfig` plus the model architecture, role, dataset
path and seqnet version. ``RUN/last.pt``: model and everything needed to resume exactly
(optimiser, scheduler, training generator, negative cache, best score and epoch, patience counter,
history). ``RUN/best.pt``: the model of the best val R@1. TensorBoard events in ``RUN/``.
``RUN/.seqnet-manifest.json``: what the run wrote (:mod:`seqnet.train.rundir`: what a new run or
``--resume`` may start again).

After an epoch, ``best.pt`` (when the epoch is the best) is written **before** ``last.pt``, each
atomically: whatever the crash point, the best epoch ``last.pt`` records has its ``best.pt``
(after a crash between the two, resuming repeats that epoch exactly and rewrites both; in epoch 1,
with no ``last.pt`` yet, the run starts again). A write cut short by a full disk is one line
(:class:`ResourceError`, exit 1) saying what the directory holds and how to continue.
"""

from __future__ import annotations

import dataclasses
import errno
import logging
import math
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .._version import __version__
from ..core.errors import CheckpointError, ConfigError, ResourceError
from ..core.lazy import lazy_module
from ..core.log import logger
from ..security.dirs import remove_dead_temps
from ..security.files import write_json_atomic
from ..security.ownership import MANIFEST
from ..sequence.checkpoints import CHECKPOINT_FORMAT, check_architecture, read_checkpoint, save_checkpoint
from .config import OPTIMIZERS, RESUME_OVERRIDABLE, TrainConfig, stored_config
from .distributed import World
from .rundir import EVENTS_MARK, RUN_NAMES, check_links, claim, explain_config, restart_payload
from .state import restore

torch = lazy_module("torch")

if TYPE_CHECKING:
    from ..sequence.model import SeqNet

@dataclasses.dataclass
class Run:
    """A training run: model, optimiser, scheduler, generator, negative cache, progress and logs.

    ``world``: the training processes (rank 0 alone writes files); ``net``: what the training step
    calls, the model or its DistributedDataParallel (None: the model); ``advice``: the warnings the guide logged
    on rank 0 (the plan's advice, a val split too small, why training stopped early; :mod:`seqnet.train.guide`)."""

    conf: TrainConfig
    model: SeqNet
    optimizer: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.LRScheduler
    generator: torch.Generator  # CPU generator of every random draw of training (order, negative sampling)
    neg_cache: torch.Tensor  # [M, K] previous hard negatives per training query (-1 = none)
    out_dir: Path
    dataset_path: str | None = None
    dataset_digests: dict[str, str] | None = None  # the descriptor files' recorded hashes (train.state)
    record: dict[str, Any] = dataclasses.field(default_factory=dict)  # train/val ranges (train.record.data_record)
    writer: Any = None
    epoch: int = 0
    best_score: float = -math.inf
    best_epoch: int = 0
    bad_epochs: int = 0
    history: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    advice: list[str] = dataclasses.field(default_factory=list)
    world: World = dataclasses.field(default_factory=World)
    net: torch.nn.Module | None = None

    @property
    def should_stop(self) -> bool:
        """Early stopping: ``patience`` epochs in a row without a better val R@1."""
        return self.conf.patience is not None and self.bad_epochs >= self.conf.patience

    def train_state(self) -> dict[str, Any]:
        """What ``last.pt`` needs beyond the model to resume exactly."""
        return {"optimizer": self.optimizer.state_dict(), "scheduler": self.scheduler.state_dict(),
                "rng": {"generator": self.generator.get_state()}, "neg_cache": self.neg_cache.clone(),
                "best_epoch": self.best_epoch, "bad_epochs": self.bad_epochs, "history": self.history}

    def close(self, failed: bool = False) -> None:
        """Close the TensorBoard writer; one that cannot write its last events (a full disk) is a warning (a
        debug line when the run ``failed``: its error is the one line): the checkpoints are what the run keeps."""
        if self.writer is not None:
            try:
                self.writer.close()
            except OSError as e:
                logger.log(logging.DEBUG if failed else logging.WARNING, "could not finish writing the TensorBoard "
                           "events in %s (%s)", self.out_dir, e.strerror or e)


def read_resume(src: str | Path) -> dict[str, Any]:
    """The checkpoint to resume (``src``: a run directory or its ``last.pt``), checked to hold a run: its
    format, architecture against its weights, configuration and dataset path. A run directory without
    ``last.pt`` whose files are all seqnet's gives what starts it again
    (:func:`seqnet.train.rundir.restart_payload`)."""
    src = Path(src)
    if src.is_dir():
        check_links(src)
        if not (src / "last.pt").exists():
            return restart_payload(src)
    path = src / "last.pt" if src.is_dir() else src
    if path.is_symlink():
        raise CheckpointError(f"{path} is a symbolic link; seqnet resumes a run from its own last.pt, not through "
                              "a link (hint: remove the link, or --resume the run directory it belongs to)")
    payload = read_checkpoint(path)
    fmt = payload.get("format")
    if fmt != CHECKPOINT_FORMAT:
        newer = isinstance(fmt, str) and fmt.startswith("seqnet-checkpoint/")
        raise CheckpointError(f"{path} is a checkpoint of format {str(fmt)[:40]!r}" + (
            f", written by a newer seqnet; this seqnet reads {CHECKPOINT_FORMAT!r} (hint: upgrade seqnet)" if newer
            else ", not a seqnet training run's last.pt (hint: pass a run directory or its last.pt)"))
    if "train_state" not in payload or not isinstance(payload.get("config"), Mapping):
        raise CheckpointError(f"{src} holds no training state to resume (pass a run directory or its last.pt)")
    check_architecture(payload.get("model"), payload["state_dict"], path)
    payload["config"] = stored_config(payload["config"], str(path), CheckpointError)
    stored_config({"dataset_path": payload.get("dataset_path")}, str(path), CheckpointError)
    return payload


def _stored(payload: Mapping[str, Any]) -> tuple[dict[str, Any], str | None]:
    """The stored configuration dict and dataset path (older runs kept the path in the config)."""
    config = dict(payload["config"])
    path = config.pop("dataset_path", None)
    return config, payload.get("dataset_path") or path


def resume_config(src: str | Path, **changes: Any) -> TrainConfig:
    """The configuration of the run in ``src`` (directory or ``last.pt``) with ``changes`` (None: keep)
    applied before validation (so e.g. a run on ``cuda`` can be resumed with ``device="cpu"``)."""
    config, _ = _stored(read_resume(src))
    return TrainConfig.from_dict({**config, **{k: v for k, v in changes.items() if v is not None}})


def stored_dataset_path(payload: Mapping[str, Any]) -> str | None:
    """The dataset path recorded in a run's checkpoint ``payload``, if any."""
    return _stored(payload)[1]


def run_dataset_path(src: str | Path) -> str | None:
    """The dataset path recorded in the run in ``src`` (directory or ``last.pt``), if any."""
    return stored_dataset_path(read_resume(src))


def check_epochs_left(done: Any, epochs: int, run: str | Path) -> None:
    """Refuse to resume the run in ``run`` (trained to epoch ``done``; None: not known, nothing checked) with
    ``epochs`` (the total, as when it started) not above the epochs it has done: nothing would be trained."""
    if isinstance(done, int) and not isinstance(done, bool) and epochs <= done:
        raise ConfigError(f"{run} is already trained to epoch {done}; --epochs {epochs} is the total number of "
                          f"epochs (not more to run): give --epochs {done + 1} or more")


def restored_config(payload: Mapping[str, Any], conf: TrainConfig | None) -> TrainConfig:
    """The stored configuration of the run in ``payload`` with the changes ``conf`` makes (None: none);
    only epochs, patience and device may differ (:meth:`TrainConfig.resumed`)."""
    config, _ = _stored(payload)
    device = {"device": conf.device} if conf is not None else {}  # the run's device may not exist here
    return TrainConfig.from_dict({**config, **device}).resumed(conf)


RUN_FILES = RUN_NAMES


def is_run_file(rel: str) -> bool:
    """Whether ``rel`` (a path inside a run directory) is a file a training run writes there (by its name: for
    directories without a manifest, :func:`seqnet.security.ownership.foreign_files`)."""
    return rel in RUN_FILES or rel == MANIFEST or (("/" not in rel) and rel.startswith("events.out.tfevents."))


def _new_model(conf: TrainConfig, in_dims: int, device: torch.device) -> SeqNet:
    """The model initialised from ``conf.seed`` without touching the process's random state."""
    with torch.random.fork_rng(devices=[]):
        torch.random.default_generator.manual_seed(conf.seed)
        from ..sequence.model import SeqNet  # the model class loads torch

        model = SeqNet(in_dims, int(conf.out_dims or in_dims), conf.seq_len, conf.w)
    return model.to(device)


def open_run(conf: TrainConfig, n_queries: int, in_dims: int, device: torch.device, out_dir: Path,
             payload: Mapping[str, Any] | None = None, dataset_path: str | None = None, files: bool = True,
             n_refs: int | None = None) -> Run:
    """A fresh run, or the one stored in ``payload`` (a ``last.pt``, checked against the run:
    :func:`seqnet.train.state.restore`; ``n_refs``: the training reference windows); with ``files``, its
    files are opened (:func:`open_files`)."""
    model = _new_model(conf, in_dims, device)
    opt = OPTIMIZERS[conf.optimizer]([p for p in model.parameters() if p.requires_grad], conf)
    sched = torch.optim.lr_scheduler.StepLR(opt, step_size=conf.lr_step, gamma=conf.lr_gamma)
    cache = torch.full((n_queries, conf.n_negatives), -1, dtype=torch.long)
    run = Run(conf, model, opt, sched, torch.Generator().manual_seed(conf.seed), cache, out_dir, dataset_path)
    if payload is not None:
        restore(run, payload, n_refs)
    if files:
        open_files(run)
    return run


def open_files(run: Run) -> None:
    """Create the run directory, record it in its manifest (:func:`seqnet.train.rundir.claim`), remove the
    temporary files a killed run left there, write ``config.json`` (when resuming, saying where the old one
    disagreed with ``last.pt``) and open the TensorBoard writer (events after a restored epoch are dropped)."""
    from torch.utils.tensorboard import SummaryWriter

    out = run.out_dir
    out.mkdir(parents=True, exist_ok=True)
    check_links(out)
    claim(out, adopt=bool(run.epoch))
    remove_dead_temps([out / n for n in (*RUN_NAMES, MANIFEST)])
    config = {**run.conf.to_dict(), "model": run.model.config(), "role": run.model.role,
              "dataset_path": run.dataset_path, "seqnet_version": __version__}
    if run.epoch:
        explain_config(out / "config.json", config, (*RESUME_OVERRIDABLE, "dataset_path"))
    write_json_atomic(out / "config.json", config)
    run.writer = SummaryWriter(log_dir=str(out), purge_step=run.epoch + 1 if run.epoch else None,
                               filename_suffix=EVENTS_MARK)
    claim(out)  # the events file just opened


def finish_epoch(run: Run, epoch: int, stats: Mapping[str, float], metrics: Mapping[str, float],
                 seconds: float) -> bool:
    """Step the schedule, update best / patience, write ``best.pt`` (when improved) then ``last.pt`` and
    TensorBoard scalars (rank 0 only), log a debug line. Returns whether the epoch is the best so far."""
    lr = run.optimizer.param_groups[0]["lr"]
    with warnings.catch_warnings():  # an epoch without an active triplet made no optimiser step: the schedule
        warnings.filterwarnings("ignore", r"Detected call of `lr_scheduler\.step\(\)` before", UserWarning)
        run.scheduler.step()  # still counts the epoch (the warning is torch's, about the call order)
    score = metrics.get("recall@1", math.nan)
    improved = math.isnan(score) or score > run.best_score  # no validation score: best.pt = last.pt
    run.epoch = epoch
    if improved:
        run.best_score, run.best_epoch, run.bad_epochs = score, epoch, 0
    else:
        run.bad_epochs += 1
    run.history.append({"epoch": epoch, "lr": lr, **stats, **metrics})
    fields = {"epoch": epoch, "best_score": run.best_score, "best_epoch": run.best_epoch, "metrics": dict(metrics),
              "config": run.conf.to_dict(), "dataset_path": run.dataset_path, "dataset_digests": run.dataset_digests,
              **run.record}
    if run.world.is_rank0:
        if improved:
            _save(run, "best.pt", fields)
        _save(run, "last.pt", {**fields, "train_state": run.train_state()})
        try:
            _log_scalars(run, epoch, lr, stats, metrics)
        except OSError as e:
            if e.errno not in _FULL:
                raise
            raise ResourceError(f"disk full (or a file size limit, ulimit -f) writing the TensorBoard events in "
                                f"{run.out_dir} in epoch {epoch}; {run.out_dir} holds the run as of epoch {epoch} "
                                f"(last.pt) (hint: check the free space, then seqnet train --resume {run.out_dir})") \
                from e
    val = ", ".join(f"R@{k.split('@')[1]} {v:.3f}" for k, v in metrics.items()) or "-"
    logger.debug("epoch %d/%d: loss %.4f, %d active of %d triplets, lr %.3g, val %s%s (%.1f s)", epoch,
                 run.conf.epochs, stats["loss"], stats["active"], stats["triplets"], lr, val,
                 " *best*" if improved and metrics else "", seconds)
    return improved


_FULL = (errno.ENOSPC, errno.EFBIG, errno.EDQUOT)


def _save(run: Run, name: str, fields: dict[str, Any]) -> None:
    """``RUN/name`` written atomically; a write cut short (full disk, file size limit) is one line saying what
    the run directory still holds and the command that continues."""
    path = run.out_dir / name
    try:
        save_checkpoint(path, run.model, **fields)
    except (ResourceError, OSError) as e:
        if not isinstance(e, ResourceError) and getattr(e, "errno", None) not in _FULL:
            raise
        saved = fields["epoch"] - 1  # last.pt on disk: the epoch before (written, or the run would have stopped)
        kept = (f"{run.out_dir} still holds the run as of epoch {saved} (last.pt)" if saved else
                f"no epoch of the run in {run.out_dir} is saved yet")
        again = f"seqnet train --resume {run.out_dir}" if saved else \
            f"run the same command again, or seqnet train --resume {run.out_dir}: either starts the run from epoch 1"
        raise ResourceError(f"disk full (or a file size limit, ulimit -f) writing {path} in epoch {fields['epoch']}; "
                            f"{kept} (hint: check the free space, then {again})") from e


def _log_scalars(run: Run, epoch: int, lr: float, stats: Mapping[str, float], metrics: Mapping[str, float]) -> None:
    scalars = {"train/loss": stats["loss"], "train/active_triplets": stats["active"],
               "train/triplets": stats["triplets"], "train/skipped_queries": stats["skipped"], "train/lr": lr,
               **{f"val/{k}": v for k, v in metrics.items()}}
    for key, value in scalars.items():
        run.writer.add_scalar(key, value, epoch)
    run.writer.flush()
