"""A training run and its directory: state, opening (fresh or from ``RUN/last.pt``) and the files
written after every epoch.

``RUN/config.json``: the resolved :class:`TrainConfig` plus the model architecture, role, dataset
path and seqnet version. ``RUN/last.pt``: model and everything needed to resume exactly
(optimiser, scheduler, training generator, negative cache, best score and epoch, patience counter,
history). ``RUN/best.pt``: the model of the best val R@1. TensorBoard events in ``RUN/``.

After an epoch, ``best.pt`` (when the epoch is the best) is written **before** ``last.pt``, each
atomically: whatever the crash point, the best epoch ``last.pt`` records has its ``best.pt``
(after a crash between the two, resuming repeats that epoch exactly and rewrites both).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .._version import __version__
from ..core.errors import CheckpointError, ConfigError
from ..core.lazy import lazy_module
from ..core.utils import logger
from ..security.files import write_json_atomic
from ..sequence.checkpoints import read_checkpoint, save_checkpoint
from .config import OPTIMIZERS, TrainConfig
from .distributed import World

torch = lazy_module("torch")

if TYPE_CHECKING:
    from ..sequence.model import SeqNet

TEMP_PATTERNS = (".last.pt.*.tmp", ".best.pt.*.tmp", ".config.json.*.tmp")  # left by a crash in an atomic write


@dataclasses.dataclass
class Run:
    """A training run: model, optimiser, scheduler, generator, negative cache, progress and logs.

    ``world``: the training processes (rank 0 alone writes files); ``net``: what the training step
    calls, the model or its DistributedDataParallel (None: the model)."""

    conf: TrainConfig
    model: SeqNet
    optimizer: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.LRScheduler
    generator: torch.Generator  # CPU generator of every random draw of training (order, negative sampling)
    neg_cache: torch.Tensor  # [M, K] previous hard negatives per training query (-1 = none)
    out_dir: Path
    dataset_path: str | None = None
    writer: Any = None
    epoch: int = 0
    best_score: float = -math.inf
    best_epoch: int = 0
    bad_epochs: int = 0
    history: list[dict[str, Any]] = dataclasses.field(default_factory=list)
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

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


def read_resume(src: str | Path) -> dict[str, Any]:
    """The checkpoint to resume (``src``: a run directory or its ``last.pt``), checked to hold a run."""
    src = Path(src)
    payload = read_checkpoint(src / "last.pt" if src.is_dir() else src)
    if "train_state" not in payload or not isinstance(payload.get("config"), Mapping):
        raise CheckpointError(f"{src} holds no training state to resume (pass a run directory or its last.pt)")
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


def restored_config(payload: Mapping[str, Any], conf: TrainConfig | None) -> TrainConfig:
    """The stored configuration of the run in ``payload`` with the changes ``conf`` makes (None: none);
    only epochs, patience and device may differ (:meth:`TrainConfig.resumed`)."""
    config, _ = _stored(payload)
    device = {"device": conf.device} if conf is not None else {}  # the run's device may not exist here
    return TrainConfig.from_dict({**config, **device}).resumed(conf)


def check_run_dir(out_dir: Path) -> None:
    """A new run needs an absent or empty directory, or one a run left before its first epoch ended (only
    its ``config.json``, TensorBoard events and temporary files: nothing to resume), which it starts again."""
    if out_dir.exists() and not out_dir.is_dir():
        raise ConfigError(f"run directory {out_dir} is a file (hint: another --out)")
    if not out_dir.exists() or not any(out_dir.iterdir()):
        return
    files = [p for p in out_dir.iterdir()]
    ours = all(p.is_file() and (is_run_file(p.name) or any(p.match(g) for g in TEMP_PATTERNS)) for p in files)
    if ours and not (out_dir / "last.pt").exists() and not (out_dir / "best.pt").exists():
        logger.info("%s holds a run that stopped before its first epoch ended; starting it again", out_dir)
        for p in files:
            p.unlink()
        return
    raise ConfigError(f"run directory {out_dir} is not empty (hint: another --out, or --resume {out_dir})")


RUN_FILES = ("last.pt", "best.pt", "config.json")


def is_run_file(rel: str) -> bool:
    """Whether ``rel`` (a path inside a run directory) is a file a training run writes there."""
    return rel in RUN_FILES or (("/" not in rel) and rel.startswith("events.out.tfevents."))


def remove_temp_files(out_dir: Path) -> list[Path]:
    """Delete the temporary files a crash during an atomic write left in ``out_dir``; returns them."""
    found = sorted(p for pattern in TEMP_PATTERNS for p in out_dir.glob(pattern) if p.is_file())
    for p in found:
        p.unlink()
        logger.debug("removed %s, left by an interrupted write", p)
    return found


def _new_model(conf: TrainConfig, in_dims: int, device: torch.device) -> SeqNet:
    """The model initialised from ``conf.seed`` without touching the process's random state."""
    with torch.random.fork_rng(devices=[]):
        torch.random.default_generator.manual_seed(conf.seed)
        from ..sequence.model import SeqNet  # the model class loads torch

        model = SeqNet(in_dims, int(conf.out_dims or in_dims), conf.seq_len, conf.w)
    return model.to(device)


def open_run(conf: TrainConfig, n_queries: int, in_dims: int, device: torch.device, out_dir: Path,
             payload: Mapping[str, Any] | None = None, dataset_path: str | None = None, files: bool = True) -> Run:
    """A fresh run, or the one stored in ``payload`` (a ``last.pt``); with ``files``, its files are
    opened (:func:`open_files`)."""
    model = _new_model(conf, in_dims, device)
    opt = OPTIMIZERS[conf.optimizer]([p for p in model.parameters() if p.requires_grad], conf)
    sched = torch.optim.lr_scheduler.StepLR(opt, step_size=conf.lr_step, gamma=conf.lr_gamma)
    cache = torch.full((n_queries, conf.n_negatives), -1, dtype=torch.long)
    run = Run(conf, model, opt, sched, torch.Generator().manual_seed(conf.seed), cache, out_dir, dataset_path)
    if payload is not None:
        _restore(run, payload)
    if files:
        open_files(run)
    return run


def open_files(run: Run) -> None:
    """Create the run directory, remove temporary files a crash left there, write ``config.json`` and
    open the TensorBoard writer (events after a restored epoch are dropped)."""
    from torch.utils.tensorboard import SummaryWriter

    run.out_dir.mkdir(parents=True, exist_ok=True)
    remove_temp_files(run.out_dir)
    write_json_atomic(run.out_dir / "config.json", {**run.conf.to_dict(), "model": run.model.config(),
                                                    "role": run.model.role, "dataset_path": run.dataset_path,
                                                    "seqnet_version": __version__})
    run.writer = SummaryWriter(log_dir=str(run.out_dir), purge_step=run.epoch + 1 if run.epoch else None)


TRAIN_STATE = ("optimizer", "scheduler", "neg_cache", "rng", "best_epoch", "bad_epochs", "history")


def _restore(run: Run, payload: Mapping[str, Any]) -> None:
    st = payload.get("train_state")
    missing = [k for k in TRAIN_STATE if not isinstance(st, Mapping) or k not in st]
    missing += [k for k in ("state_dict", "model", "epoch", "best_score") if k not in payload]
    if missing or not isinstance(st.get("neg_cache"), torch.Tensor) or not isinstance(st.get("rng"), Mapping):
        what = ", ".join(missing) or "a negative cache tensor and random state"
        raise CheckpointError(f"{run.out_dir / 'last.pt'} lacks what resuming needs ({what}); it was not written "
                              "by a seqnet training run of this version (hint: start a new run)")
    if tuple(st["neg_cache"].shape) != tuple(run.neg_cache.shape) or payload["model"] != run.model.config():
        raise CheckpointError(f"the checkpoint does not fit this dataset: {tuple(st['neg_cache'].shape)[0]} training "
                              f"queries and model {payload['model']}, now {run.neg_cache.shape[0]} and "
                              f"{run.model.config()} (hint: resume with the dataset the run was trained on)")
    run.model.load_state_dict(payload["state_dict"])
    run.optimizer.load_state_dict(st["optimizer"])
    run.scheduler.load_state_dict(st["scheduler"])
    run.neg_cache.copy_(st["neg_cache"])
    run.generator.set_state(st["rng"]["generator"])
    run.epoch, run.best_score = int(payload["epoch"]), float(payload["best_score"])
    run.best_epoch, run.bad_epochs = int(st["best_epoch"]), int(st["bad_epochs"])
    run.history = list(st["history"])


def finish_epoch(run: Run, epoch: int, stats: Mapping[str, float], metrics: Mapping[str, float],
                 seconds: float) -> bool:
    """Step the schedule, update best / patience, write ``best.pt`` (when improved) then ``last.pt`` and
    TensorBoard scalars (rank 0 only), log a debug line. Returns whether the epoch is the best so far."""
    lr = run.optimizer.param_groups[0]["lr"]
    run.scheduler.step()
    score = metrics.get("recall@1", math.nan)
    improved = math.isnan(score) or score > run.best_score  # no validation score: best.pt = last.pt
    run.epoch = epoch
    if improved:
        run.best_score, run.best_epoch, run.bad_epochs = score, epoch, 0
    else:
        run.bad_epochs += 1
    run.history.append({"epoch": epoch, "lr": lr, **stats, **metrics})
    fields = {"epoch": epoch, "best_score": run.best_score, "best_epoch": run.best_epoch, "metrics": dict(metrics),
              "config": run.conf.to_dict(), "dataset_path": run.dataset_path}
    if run.world.is_rank0:
        if improved:
            save_checkpoint(run.out_dir / "best.pt", run.model, **fields)
        save_checkpoint(run.out_dir / "last.pt", run.model, **fields, train_state=run.train_state())
        _log_scalars(run, epoch, lr, stats, metrics)
    val = ", ".join(f"R@{k.split('@')[1]} {v:.3f}" for k, v in metrics.items()) or "-"
    logger.debug("epoch %d/%d: loss %.4f, %d active of %d triplets, lr %.3g, val %s%s (%.1f s)", epoch,
                 run.conf.epochs, stats["loss"], stats["active"], stats["triplets"], lr, val,
                 " *best*" if improved and metrics else "", seconds)
    return improved


def _log_scalars(run: Run, epoch: int, lr: float, stats: Mapping[str, float], metrics: Mapping[str, float]) -> None:
    scalars = {"train/loss": stats["loss"], "train/active_triplets": stats["active"],
               "train/triplets": stats["triplets"], "train/skipped_queries": stats["skipped"], "train/lr": lr,
               **{f"val/{k}": v for k, v in metrics.items()}}
    for key, value in scalars.items():
        run.writer.add_scalar(key, value, epoch)
    run.writer.flush()
