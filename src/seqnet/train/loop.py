"""Training SeqNet (S_L, and S_1 with ``seq_len = w = 1``) with a triplet loss and hard negatives.

Queries are windows of the query traverse of the train split, positives/negatives windows of its
reference traverse (see :mod:`seqnet.train.mining`). Each epoch visits every query with a positive
and a negative, in random order; every ``cache_refresh`` queries the descriptors used for mining are
recomputed by the current model. After each epoch the model is validated (Recall@1/5/10/20 on the
val split) and the run's files are written (:mod:`seqnet.train.run`). Settings:
:class:`~seqnet.train.config.TrainConfig` (the paper's defaults).

Logging: one INFO line when training starts and one when it ends; one DEBUG line per epoch
(``seqnet -v``); one progress bar per epoch (:func:`seqnet.progress.progress`).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import torch

from ..data.io import load_dataset
from ..data.traverse import Dataset
from ..errors import ConfigError, DatasetError, OutputError
from ..ownership import locked
from ..progress import progress
from ..provenance import check_same
from ..sequence_descriptors import SeqNet
from ..utils import get_device, logger
from ..windows import gather_windows
from .config import TrainConfig
from .losses import triplet_loss
from .mining import Mined, TripletSource, compute_cache, mine_queries, split_windows, triplet_source
from .run import (
    Run,
    check_run_dir,
    finish_epoch,
    open_run,
    read_resume,
    remove_temp_files,
    restored_config,
    run_dataset_path,
    stored_dataset_path,
)

VAL_KS = (1, 5, 10, 20)
STAT_KEYS = ("loss", "queries", "skipped", "triplets", "active")


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
    out = triplet_loss(emb[:b], emb[b : 2 * b], emb[2 * b :], valid.nonzero()[:, 0], run.conf.margin)
    run.optimizer.zero_grad(set_to_none=True)
    out.loss.backward()
    run.optimizer.step()
    stats.update(triplets=float(out.triplets), active=float(out.active), loss=float(out.loss.detach()))
    return stats


def train_epoch(run: Run, src: TripletSource, epoch: int) -> dict[str, float]:
    """One pass over every training query (shuffled); every ``cache_refresh`` queries the mining
    descriptors are recomputed and those queries' triplets mined. Returns the mean batch loss and
    summed counts (queries, skipped, triplets, active). One progress bar, with loss / active."""
    n, bs, mining = src.n_queries, run.conf.batch_size, run.conf.mining
    order = torch.randperm(n, generator=run.generator).to(src.q_idx.device)
    chunk = mining.cache_refresh or n
    totals = dict.fromkeys(STAT_KEYS, 0.0)
    steps = 0
    n_batches = sum(math.ceil(min(chunk, n - s) / bs) for s in range(0, n, chunk))
    with progress(total=n_batches, desc=f"epoch {epoch}/{run.conf.epochs}", unit="batch") as bar:
        for s in range(0, n, chunk):
            sub = order[s : s + chunk]
            q_feat, r_feat = compute_cache(run.model, src, sub)
            mined = mine_queries(src, sub, q_feat, r_feat, mining, run.generator, run.neg_cache)
            for b in range(0, len(sub), bs):
                st = train_step(run, src, sub[b : b + bs], mined[b : b + bs])
                steps += st["triplets"] > 0
                totals = {k: v + st[k] for k, v in totals.items()}
                bar.update(1)
                if not bar.disable:
                    bar.set_postfix(loss=f"{st['loss']:.4f}", active=int(st["active"]), refresh=False)
    totals["loss"] /= max(steps, 1)
    return totals


def validate(model: SeqNet, val_ds: Dataset | None, conf: TrainConfig) -> dict[str, float]:
    """Recall@1/5/10/20 of ``model`` on the validation split (method "seqnet" for S_L, "s1" for S_1);
    ``{}`` without a val split. Leaves the model in training mode."""
    from ..evaluate import EvalConfig, evaluate

    if val_ds is None:
        return {}
    role = model.role
    ev_conf = EvalConfig(methods=(role,), seq_len=model.seq_len, window=conf.window, ks=VAL_KS, device=conf.device)
    ev = evaluate(val_ds, ev_conf, {role: model})
    model.train()
    return {k: float(v) for k, v in ev.results["methods"][role].items() if k.startswith("recall@")}


def _split(ds: Dataset, name: str, what: str) -> Dataset:
    try:
        return ds.split(name)
    except DatasetError as e:
        hint = " or none to skip validation" if what == "val" else " (all: the whole dataset)"
        raise DatasetError(f"{e} (hint: --{what}-split NAME{hint})") from None


def prepare(dataset: Dataset, conf: TrainConfig, device: torch.device) -> tuple[TripletSource, Dataset | None]:
    """The training windows on ``device`` and the val split (None: no validation), both checked
    (windows fit, some query has a positive and a negative): everything that can fail on the data
    fails here, before a run directory is created."""
    src = triplet_source(_split(dataset, conf.train_split, "train"), conf.seq_len, conf.window, conf.mining, device)
    if not conf.validates:
        return src, None
    val_ds = _split(dataset, conf.val_split, "val")
    split_windows(val_ds, conf.seq_len, conf.window, conf.mining, "val")
    return src, val_ds


def _name(model: SeqNet) -> str:
    return "S_1" if model.role == "s1" else f"S_{model.seq_len}"


def _fit(run: Run, src: TripletSource, val_ds: Dataset | None, device: torch.device) -> None:
    """The epochs from the run's next one to ``conf.epochs`` (or early stopping), with the two INFO lines."""
    first, m = run.epoch + 1, run.model
    resumed = f"resuming {run.out_dir} after epoch {run.epoch}: " if run.epoch else ""
    val = f"validating on {val_ds.name}" if val_ds is not None else "no validation"
    left = f" ({src.left_out} more without a positive or a negative left out)" if src.left_out else ""
    logger.info("%straining %s (w=%d, D %d->%d) on %d queries%s, %d reference windows, epochs %d..%d, device %s, %s",
                resumed, _name(m), m.w, m.in_dims, m.out_dims, src.n_queries, left, len(src.r_idx), first,
                run.conf.epochs, device, val)
    t0 = time.perf_counter()
    for epoch in range(first, run.conf.epochs + 1):
        t_epoch = time.perf_counter()
        stats = train_epoch(run, src, epoch)
        finish_epoch(run, epoch, stats, validate(run.model, val_ds, run.conf), time.perf_counter() - t_epoch)
        if run.should_stop:
            break
    best = (f"best val R@1 {run.best_score:.4f} at epoch {run.best_epoch}" if val_ds is not None and run.best_epoch
            else "no validation (best.pt = last.pt)")
    early = run.should_stop and run.epoch < run.conf.epochs
    stop = f"; early stop: no better val R@1 for {run.bad_epochs} epochs" if early else ""
    n = run.epoch - first + 1
    logger.info("trained %s for %d epoch%s (to epoch %d) in %.1f s; %s%s", _name(m), n, "" if n == 1 else "s",
                run.epoch, time.perf_counter() - t0, best, stop)


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
               "the query descriptors", allow_mismatch)
    with locked(out_dir):  # a second writer of this run is refused
        payload = None
        if resume:
            payload = read_resume(out_dir if resume is True else Path(resume))
            conf = restored_config(payload, conf)
            dataset_path = dataset_path or stored_dataset_path(payload)
        else:
            conf = (conf or TrainConfig()).resolve(dataset)
            check_run_dir(out_dir)
        device = get_device(conf.device)
        src, val_ds = prepare(dataset, conf, device)
        out_dir.mkdir(parents=True, exist_ok=True)
        remove_temp_files(out_dir)
        run = open_run(conf, src.n_queries, dataset.query.dim, device, out_dir, payload,
                       str(dataset_path) if dataset_path is not None else None)
        run.model.provenance = dataset.reference.provenance  # checkpoints record what the model reads
        try:
            _fit(run, src, val_ds, device)
        finally:
            run.close()
    return run


def check_resume_target(resume: bool | str | Path, out_dir: Path) -> None:
    """``--resume A`` writes only to A: an ``out_dir`` naming another directory is an error."""
    if not resume or resume is True:
        return
    src = Path(resume)
    run_dir = src.parent if src.is_file() else src
    if run_dir.resolve() != out_dir.resolve():
        raise OutputError(f"--resume {resume} continues the run in {run_dir}, but --out names another directory "
                          f"{out_dir}; a resumed run is written where it is (hint: drop --out, or copy the run "
                          "directory first and resume the copy)")


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
    run = train(load_dataset(path), conf, out, resume=resume or False, dataset_path=Path(path).resolve(),
                allow_mismatch=allow_mismatch)
    return run.out_dir

