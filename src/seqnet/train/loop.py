"""Training SeqNet (S_L, and S_1 with ``seq_len = w = 1``) with a triplet loss and hard negatives.

Queries are windows of the query traverse of the train split, positives/negatives windows of its
reference traverse (see :mod:`seqnet.mining`). Each epoch visits every query with a positive, in
random order; every ``cache_refresh`` queries the descriptors used for mining are recomputed by the
current model. After each epoch the model is validated (Recall@1/5/10/20 on the val split) and
``RUN/last.pt`` / ``RUN/best.pt`` (best val R@1) are written atomically, with everything needed
to resume exactly; ``RUN/config.json`` holds the resolved configuration and ``RUN/`` the
TensorBoard logs. Defaults: :data:`TRAIN_CONFIG_DEFAULTS` (the paper's).
"""

from __future__ import annotations

import dataclasses
import math
import random
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from .. import __version__
from ..config_legacy import TRAIN_DEFAULTS, merge
from ..data.io import load_dataset
from ..data.traverse import Dataset
from ..errors import CheckpointError, ConfigError, DatasetError
from ..files import write_json_atomic
from ..sequence_descriptors import SeqNet
from ..utils import get_device, logger
from ..windows import WINDOW_MODES, check_seq_len, gather_windows
from .checkpoints import capture_rng, model_role, read_checkpoint, read_resume, restore_rng, save_checkpoint
from .losses import triplet_loss
from .mining import Mined, TripletSource, check_radii, compute_cache, mine_queries, triplet_source

# Keys beyond seqnet.config.TRAIN_DEFAULTS (belong there): the splits used for training / validation.
TRAIN_CONFIG_DEFAULTS = TRAIN_DEFAULTS  # the single source of training defaults (seqnet.config)
RESUME_OVERRIDABLE = ("epochs", "patience", "device")
VAL_KS = [1, 5, 10, 20]


def resolve_train_config(overrides: Mapping[str, Any] | None, ds: Dataset) -> dict[str, Any]:
    """Merge ``overrides`` onto :data:`TRAIN_CONFIG_DEFAULTS`, fill dataset-dependent defaults
    (out_dims; radii from ``dataset.extra`` else the localisation radius and 4×) and validate."""
    cfg = merge(TRAIN_CONFIG_DEFAULTS, overrides)
    cfg["seq_len"] = check_seq_len(cfg["seq_len"])
    if not 1 <= int(cfg["w"]) <= cfg["seq_len"]:
        raise ConfigError(f"w must be in 1..seq_len={cfg['seq_len']}, got w={cfg['w']} (S_1: --seq-len 1 --w 1)")
    cfg["out_dims"] = int(cfg["out_dims"] or ds.query.dim)
    cfg["optimizer"] = str(cfg["optimizer"]).lower()
    if cfg["optimizer"] not in ("sgd", "adam"):
        raise ConfigError(f"optimizer {cfg['optimizer']!r} is not one of ('sgd', 'adam')")
    if cfg["window"] not in WINDOW_MODES:
        raise ConfigError(f"window {cfg['window']!r} is not one of {WINDOW_MODES}")
    for key in ("lr", "margin", "lr_gamma"):
        if not float(cfg[key]) > 0:
            raise ConfigError(f"{key} must be > 0, got {cfg[key]}")
    for key in ("batch_size", "epochs", "n_negatives", "n_neg_sample", "lr_step", "out_dims"):
        if int(cfg[key]) < 1:
            raise ConfigError(f"{key} must be an integer >= 1, got {cfg[key]}")
    if int(cfg["cache_refresh"]) < 0 or (cfg["patience"] is not None and int(cfg["patience"]) < 1):
        raise ConfigError(f"need cache_refresh >= 0 (0: once per epoch) and patience >= 1 (or None), "
                          f"got {cfg['cache_refresh']} and {cfg['patience']}")
    pos = cfg["pos_radius"] or ds.extra.get("pos_radius") or ds.radius
    neg = cfg["neg_radius"] or ds.extra.get("neg_radius") or 4 * float(pos)
    cfg["pos_radius"], cfg["neg_radius"] = check_radii(pos, neg)
    return cfg


@dataclasses.dataclass
class Run:
    """A training run: model, optimiser, scheduler, RNG, negative cache, progress and logs."""

    cfg: dict[str, Any]
    model: SeqNet
    optimizer: torch.optim.Optimizer
    scheduler: Any
    generator: torch.Generator
    neg_cache: torch.Tensor  # [M, K] previous hard negatives per training query (-1 = none)
    out_dir: Path
    writer: Any = None
    epoch: int = 0
    best_score: float = -math.inf
    best_epoch: int = 0
    bad_epochs: int = 0
    history: list[dict[str, Any]] = dataclasses.field(default_factory=list)

    def train_state(self) -> dict[str, Any]:
        return {"optimizer": self.optimizer.state_dict(), "scheduler": self.scheduler.state_dict(),
                "rng": capture_rng(self.generator), "neg_cache": self.neg_cache.clone(), "best_epoch": self.best_epoch,
                "bad_epochs": self.bad_epochs, "history": self.history}

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


def open_run(cfg: dict[str, Any], n_queries: int, in_dims: int, device: torch.device, out_dir: Path,
             payload: Mapping[str, Any] | None = None) -> Run:
    """A fresh run (model initialised from the seeded global RNG), or the one stored in ``payload``."""
    from torch.utils.tensorboard import SummaryWriter

    model = SeqNet(in_dims, cfg["out_dims"], cfg["seq_len"], cfg["w"]).to(device)
    params = [p for p in model.parameters() if p.requires_grad]
    if cfg["optimizer"] == "adam":
        opt: torch.optim.Optimizer = torch.optim.Adam(params, lr=cfg["lr"], weight_decay=cfg["weight_decay"])
    else:
        opt = torch.optim.SGD(params, lr=cfg["lr"], momentum=cfg["momentum"], weight_decay=cfg["weight_decay"])
    sched = torch.optim.lr_scheduler.StepLR(opt, step_size=int(cfg["lr_step"]), gamma=cfg["lr_gamma"])
    cache = torch.full((n_queries, int(cfg["n_negatives"])), -1, dtype=torch.long)
    run = Run(cfg, model, opt, sched, torch.Generator().manual_seed(int(cfg["seed"])), cache, out_dir)
    if payload is not None:
        _restore(run, payload)
    write_json_atomic(out_dir / "config.json", {**cfg, "model": model.config(), "role": model_role(model),
                                                "seqnet_version": __version__})
    run.writer = SummaryWriter(log_dir=str(out_dir), purge_step=run.epoch + 1 if payload is not None else None)
    return run


def _restore(run: Run, payload: Mapping[str, Any]) -> None:
    st = payload["train_state"]
    if tuple(st["neg_cache"].shape) != tuple(run.neg_cache.shape) or payload["model"] != run.model.config():
        raise CheckpointError(f"the checkpoint does not fit this dataset: {tuple(st['neg_cache'].shape)[0]} training "
                              f"queries and model {payload['model']}, now {run.neg_cache.shape[0]} and "
                              f"{run.model.config()} (hint: resume with the dataset the run was trained on)")
    run.model.load_state_dict(payload["state_dict"])
    run.optimizer.load_state_dict(st["optimizer"])
    run.scheduler.load_state_dict(st["scheduler"])
    run.neg_cache.copy_(st["neg_cache"])
    restore_rng(st["rng"], run.generator)
    run.epoch, run.best_score = int(payload["epoch"]), float(payload["best_score"])
    run.best_epoch, run.bad_epochs = int(st["best_epoch"]), int(st["bad_epochs"])
    run.history = list(st["history"])
    logger.info("resuming %s after epoch %d (best R@1 %.4f at epoch %d)", run.out_dir, run.epoch, run.best_score,
                run.best_epoch)


def train_step(run: Run, src: TripletSource, rows: torch.Tensor, mined: Mined) -> dict[str, float]:
    """One optimiser step on all triplets of the queries ``rows [B]`` (``mined``: their triplets)."""
    keep = mined.has_triplet
    b = int(keep.sum())
    stats = {"queries": float(b), "skipped": float(len(rows) - b), "triplets": 0.0, "active": 0.0, "loss": 0.0}
    if b == 0:
        return stats
    valid = mined.valid[keep]
    ref = torch.cat([mined.positive[keep], mined.negatives[keep][valid]])
    windows = torch.cat([gather_windows(src.q_desc, src.q_idx[rows[keep]]), gather_windows(src.r_desc, src.r_idx[ref])])
    emb = run.model(windows)  # [B + B + T, D']: queries, positives, negatives
    out = triplet_loss(emb[:b], emb[b : 2 * b], emb[2 * b :], valid.nonzero()[:, 0], run.cfg["margin"])
    run.optimizer.zero_grad(set_to_none=True)
    out.loss.backward()
    run.optimizer.step()
    stats.update(triplets=float(out.triplets), active=float(out.active), loss=float(out.loss.detach()))
    return stats


def train_epoch(run: Run, src: TripletSource, epoch: int) -> dict[str, float]:
    """One pass over every training query (shuffled); every ``cache_refresh`` queries the mining
    descriptors are recomputed and those queries' triplets mined. Returns the mean batch loss and counts."""
    n, bs = src.n_queries, int(run.cfg["batch_size"])
    order = torch.randperm(n, generator=run.generator).to(src.q_idx.device)
    chunk = int(run.cfg["cache_refresh"]) or n
    totals = dict.fromkeys(("loss", "queries", "skipped", "triplets", "active"), 0.0)
    steps = 0
    n_batches = sum(math.ceil(min(chunk, n - s) / bs) for s in range(0, n, chunk))
    with tqdm(total=n_batches, desc=f"epoch {epoch}/{run.cfg['epochs']}", leave=False, disable=None) as bar:
        for s in range(0, n, chunk):
            sub = order[s : s + chunk]
            q_feat, r_feat = compute_cache(run.model, src, sub)
            mined = mine_queries(src, sub, q_feat, r_feat, run.cfg, run.generator, run.neg_cache)
            for b in range(0, len(sub), bs):
                st = train_step(run, src, sub[b : b + bs], mined[b : b + bs])
                steps += st["triplets"] > 0
                totals = {k: v + st[k] for k, v in totals.items()}
                bar.update(1)
                if not bar.disable:
                    bar.set_postfix(loss=f"{st['loss']:.4f}", active=int(st["active"]), refresh=False)
    totals["loss"] /= max(steps, 1)
    return totals


def validate(model: SeqNet, val_ds: Dataset | None, cfg: Mapping[str, Any]) -> dict[str, float]:
    """Recall@1/5/10/20 of ``model`` on the validation split (method "seqnet" for S_L, "s1" for S_1)."""
    from ..evaluate import EvalConfig, evaluate

    if val_ds is None:
        return {}
    role = model.role
    conf = EvalConfig(methods=(role,), seq_len=model.seq_len, window=cfg["window"], ks=tuple(VAL_KS),
                      device=cfg["device"])
    ev = evaluate(val_ds, conf, {role: model})
    model.train()
    return {k: float(v) for k, v in ev.results["methods"][role].items() if k.startswith("recall@")}


def finish_epoch(
    run: Run, epoch: int, stats: Mapping[str, float], metrics: Mapping[str, float], seconds: float
) -> bool:
    """Step the schedule, log, write ``last.pt`` (and ``best.pt``); True when early stopping says stop."""
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
    fields = {"epoch": epoch, "best_score": run.best_score, "metrics": dict(metrics), "config": run.cfg}
    save_checkpoint(run.out_dir / "last.pt", run.model, **fields, train_state=run.train_state())
    if improved:
        save_checkpoint(run.out_dir / "best.pt", run.model, **fields)
    for key, value in {"train/loss": stats["loss"], "train/active_triplets": stats["active"], "train/triplets":
                       stats["triplets"], "train/skipped_queries": stats["skipped"], "train/lr": lr,
                       **{f"val/{k}": v for k, v in metrics.items()}}.items():
        run.writer.add_scalar(key, value, epoch)
    run.writer.flush()
    val = ", ".join(f"R@{k.split('@')[1]} {v:.3f}" for k, v in metrics.items()) or "-"
    logger.info("epoch %d: loss %.4f, %d active of %d triplets, val %s%s (%.1f s)", epoch, stats["loss"],
                stats["active"], stats["triplets"], val, " *best*" if improved and metrics else "", seconds)
    patience = run.cfg["patience"]
    if patience and run.bad_epochs >= int(patience):
        logger.info("early stopping: val R@1 has not improved for %d epochs (best %.4f at epoch %d)",
                    run.bad_epochs, run.best_score, run.best_epoch)
        return True
    return False


def _split(ds: Dataset, name: str | None, what: str) -> Dataset | None:
    if what == "val" and str(name).lower() == "none":
        return None
    try:
        return ds.split(name)
    except DatasetError as e:
        hint = " or none to skip validation" if what == "val" else " (all: the whole dataset)"
        raise DatasetError(f"{e} (hint: --{what}-split NAME{hint})") from None


def train(dataset: Dataset, config: Mapping[str, Any] | None, out_dir: str | Path,
          resume: bool | str | Path = False, dataset_path: str | None = None) -> Run:
    """Train a SeqNet model on ``dataset``'s train split, validating on its val split.

    Args:
        dataset: the whole dataset (splits named by ``config["train_split"]`` / ``["val_split"]``).
        config: overrides of :data:`TRAIN_CONFIG_DEFAULTS` (when resuming: only epochs, patience, device).
        out_dir: run directory (``last.pt``, ``best.pt``, ``config.json``, TensorBoard events).
        resume: continue the run in ``out_dir`` (True), or the run in this directory / checkpoint.
        dataset_path: recorded in ``config.json`` so that ``--resume`` finds the data.

    Returns:
        The finished :class:`Run` (model, history, best score and epoch).
    """
    out_dir = Path(out_dir)
    payload = None
    if resume:
        cfg, payload = read_resume(out_dir if resume is True else Path(resume), config, RESUME_OVERRIDABLE)
    else:
        cfg = resolve_train_config(config, dataset)
        if out_dir.exists() and any(out_dir.iterdir()):
            raise ConfigError(f"run directory {out_dir} is not empty (hint: another --out, or --resume {out_dir})")
    if dataset_path is not None:
        cfg["dataset_path"] = str(dataset_path)
    random.seed(cfg["seed"])
    np.random.seed(cfg["seed"])
    torch.manual_seed(cfg["seed"])
    device = get_device(cfg["device"])
    src = triplet_source(_split(dataset, cfg["train_split"], "train"), cfg, device)
    val_ds = _split(dataset, cfg["val_split"], "val")
    out_dir.mkdir(parents=True, exist_ok=True)
    run = open_run(cfg, src.n_queries, dataset.query.dim, device, out_dir, payload)
    t0 = time.perf_counter()
    try:
        for epoch in range(run.epoch + 1, int(cfg["epochs"]) + 1):
            stats = train_epoch(run, src, epoch)
            if finish_epoch(run, epoch, stats, validate(run.model, val_ds, cfg), time.perf_counter() - t0):
                break
    finally:
        run.close()
    return run


def main(conf: Mapping[str, Any]) -> Run:
    """hloc-style entry point: ``{"dataset": DIR, "out": RUN, "resume": RUN | None, "config": {...}}``.

    When resuming without ``dataset``, the dataset path recorded in the run is used.
    """
    resume, out = conf.get("resume"), conf.get("out") or conf.get("resume")
    if out is None:
        raise ConfigError("no run directory: give --out RUN (or --resume RUN)")
    path = conf.get("dataset")
    if path is None and resume:
        src = Path(resume)
        path = read_checkpoint(src / "last.pt" if src.is_dir() else src).get("config", {}).get("dataset_path")
    if path is None:
        raise ConfigError("no dataset: give --dataset DIR")
    return train(load_dataset(path), conf.get("config"), out, resume=resume or False,
                 dataset_path=str(Path(path).resolve()))
