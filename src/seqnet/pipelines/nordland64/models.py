"""Nordland64 models: S_L and S_1 trained on PCA-projected train descriptors, the PCA folded back in."""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...core.lazy import lazy_module
from ...core.log import logger
from ...data.traverse import Dataset
from ...describe.pca import PCA, fit_pca
from ...security.dirs import remove_dead_temps
from ...security.locks import locked
from ...security.ownership import remove_owned_dir
from ...security.text import shown
from ...sequence.checkpoints import load_model, save_checkpoint
from ...train import TrainConfig, train
from ...train.run import RUN_FILES, is_run_file
from . import cache
from .config import Nordland64Config
from .data import describe_key, training_dataset

torch = lazy_module("torch")
ROLES = ("seqnet", "s1")

if TYPE_CHECKING:
    from ...sequence.model import SeqNet


def fold_pca(model: SeqNet, pca: PCA) -> SeqNet:
    """A SeqNet on raw descriptors equal to ``model(pca.transform(x, l2=False))``.

    The PCA ``y = s ⊙ (C (x − μ))`` is linear, so it merges into the first convolution:
    ``W'_k = W_k · diag(s) C`` and ``b' = b − Σ_k W'_k μ``.
    """
    proj = torch.from_numpy(pca.components * pca.scales[:, None]).double()  # [p, D]
    w = model.conv.weight.detach().double()  # [D_out, p, w]
    w_new = torch.einsum("opk,pd->odk", w, proj)  # [D_out, D, w]
    b_new = model.conv.bias.detach().double() - torch.einsum("odk,d->o", w_new, torch.from_numpy(pca.mean).double())
    from ...sequence.model import SeqNet  # the model class loads torch

    out = SeqNet(pca.input_dim, model.out_dims, model.seq_len, model.w)
    with torch.no_grad():
        out.conv.weight.copy_(w_new.float())
        out.conv.bias.copy_(b_new.float())
    return out.eval()


def train_key(conf: Nordland64Config) -> str:
    """A hash of every setting the trained models depend on (models with the same key are reused)."""
    keys = ("train_range", "val_range", "pca_dims", "pca_whiten", "symmetric", "flip", "pos_radius", "neg_radius",
            "train", "train_s1", "names_file")
    blob = json.dumps({"describe": describe_key(conf), **{k: conf.to_dict()[k] for k in keys}}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def fit_train_pca(ds: Dataset, conf: Nordland64Config) -> PCA | None:
    """PCA to ``conf.pca_dims`` of both seasons' train descriptors, None when 0.

    Capped by the data: N centred images span at most N - 1 axes, and D-dimensional ones D."""
    if not conf.pca_dims:
        return None
    a, b = ds.splits["train"]["query"]
    x = np.concatenate([ds.reference.descriptors[a:b], ds.query.descriptors[a:b]])
    dims = min(conf.pca_dims, len(x) - 1, x.shape[1])
    if dims < conf.pca_dims:
        logger.warning("PCA: %d dims asked, %d possible with %d training images", conf.pca_dims, dims, len(x))
    return fit_pca(x, dims, whiten=conf.pca_whiten, l2=False)


def train_models(ds: Dataset, conf: Nordland64Config, out: Path, flipped: np.ndarray | None = None,
                 inputs: Any = None, overwrite: bool = False) -> tuple[dict[str, SeqNet], dict[str, float]]:
    """Train S_L and S_1 (PCA-projected inputs, epoch chosen on val), fold the PCA in; save to ``out/models``.

    The models are a cache unit (:mod:`.cache`): reused only when all of them were written by one run
    with the same settings (:func:`train_key`) from the same descriptors (``inputs``: the digests of the
    descriptors unit, by default the one in ``out``); a previous training run in ``out/runs`` is replaced
    only when this cache made it and it holds nothing but a run's files (``overwrite``: also when the cache
    did not make it).
    """
    out = Path(out)
    models_dir, key = out / "models", train_key(conf)
    with locked(out):
        if inputs is None:
            inputs = cache.unit_files(out, "descriptors")
        found = cache.unit(out, "models", key, inputs)
        if found is not None and isinstance(found.get("seconds"), dict):
            logger.info("reusing the models trained with the same settings in %s", shown(models_dir))
            return {r: load_model(models_dir / f"{r}.pt") for r in ROLES}, found["seconds"]
        cache.open_unit(out, "models", cache.MODELS, overwrite)  # its key removed first
        remove_dead_temps([models_dir / f for f in ("pca.npz", *(f"{r}.pt" for r in ROLES))])
        pca = fit_train_pca(ds, conf)
        if pca is not None:
            pca.save(models_dir / "pca.npz")
        elif (models_dir / "pca.npz").is_file():
            (models_dir / "pca.npz").unlink()  # another run's: these models read the raw descriptors
        tds = training_dataset(ds, pca, conf.symmetric, flipped)
        models, seconds = {}, {}
        for role, tconf in zip(ROLES, (conf.train, conf.train_s1), strict=True):
            models[role], seconds[role] = train_one(tds, tconf.merge(device=conf.device), out, role, pca, ds)
        files = [f"models/{f}" for f in ("pca.npz", *(f"{r}.pt" for r in ROLES)) if (models_dir / f).is_file()]
        cache.seal(out, "models", key, files, seconds=seconds, inputs=inputs)
    return models, seconds


def train_one(tds: Dataset, tconf: TrainConfig, out: Path, role: str, pca: PCA | None,
              ds: Dataset) -> tuple[SeqNet, float]:
    """Train one model in ``out/runs/ROLE`` (a previous run there replaced), fold the PCA in, save it to
    ``out/models/ROLE.pt``; the model and its training seconds."""
    run_dir = out / "runs" / role
    with locked(run_dir):
        remove_dead_temps([run_dir / f for f in RUN_FILES])
        remove_owned_dir(run_dir, "training run", is_run_file)
        t0 = time.perf_counter()
        run = train(tds, tconf, run_dir)
    seconds = round(time.perf_counter() - t0, 2)
    model = load_model(run_dir / "best.pt")
    model = fold_pca(model, pca) if pca is not None else model
    model.provenance = ds.reference.provenance  # the folded model reads the raw descriptors
    save_checkpoint(out / "models" / f"{role}.pt", model, epoch=run.best_epoch, best_score=run.best_score,
                    metrics={"val_recall@1": run.best_score}, config={**tconf.to_dict(), "pca_folded": pca is not None})
    return model, seconds
