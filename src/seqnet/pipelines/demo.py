"""The built-in demo: synthetic data → train S_L and S_1 → every method → comparison table.

The demo trains with its own fast settings (:data:`DEMO_TRAIN`: Adam, a larger learning rate, a
few epochs, early stopping on the val split) instead of the paper's (SGD lr 1e-4 for up to 200
epochs), so that the whole demo runs in well under a minute on two CPU cores.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

from ..checkpoints import load_model
from ..data.io import load_dataset, save_dataset
from ..data.synth import make_synthetic
from ..data.traverse import Dataset
from ..evaluate import EvalConfig, Evaluation, evaluate
from ..train.loop import train
from ..utils import logger

BASELINES = ["single", "smoothing", "delta", "raw+seqmatch", "delta+seqmatch"]
LEARNED = ["seqnet", "s1+seqmatch", "hvpr"]  # hvpr: shortlist with S_L, re-rank by SeqMatch on S_1
DEMO_METHODS = BASELINES + LEARNED
DEMO_SEQ_LEN = 5
DEMO_PLACES = 2000
# Fast demo training settings (not the paper's): see the module docstring and docs/training.md.
DEMO_TRAIN: dict[str, Any] = {"optimizer": "adam", "lr": 1e-3, "weight_decay": 0.0, "epochs": 40, "patience": 8,
                              "out_dims": 256}
DEMO_MODELS = {"seqnet": {"seq_len": DEMO_SEQ_LEN, "w": 3}, "s1": {"seq_len": 1, "w": 1}}


def train_demo_models(ds: Dataset, root: Path, data_dir: Path, device: str = "auto",
                      epochs: int | None = None, seed: int = 0) -> tuple[dict[str, Any], dict[str, float]]:
    """Train S_L and S_1 on ``ds`` (runs in ``root/train_<role>``); returns models by role and seconds per role."""
    models, seconds = {}, {}
    for role, arch in DEMO_MODELS.items():
        t0 = time.perf_counter()
        cfg = {**DEMO_TRAIN, **arch, "device": device, "seed": seed, **({"epochs": epochs} if epochs else {})}
        run_dir = root / f"train_{role}"
        if run_dir.exists():  # a previous demo's run in --out: the demo owns it
            shutil.rmtree(run_dir)
        run = train(ds, cfg, run_dir, dataset_path=str(data_dir))
        models[role] = load_model(run.out_dir / "best.pt")
        seconds[role] = round(time.perf_counter() - t0, 2)
        logger.info("demo: trained %s in %.1f s (best val R@1 %.3f at epoch %d)", role, seconds[role],
                    run.best_score, run.best_epoch)
    return models, seconds


def run_demo(out: str | Path | None = None, places: int = DEMO_PLACES, seed: int = 0, device: str = "auto",
             epochs: int | None = None, train_models: bool = True) -> Evaluation:
    """Generate a synthetic dataset, save and reload it, train S_L and S_1, and evaluate every method.

    Args:
        out: directory to keep the dataset, training runs and results in (default: temporary).
        places: number of places along the synthetic route.
        seed: random seed (data and training).
        device: torch device.
        epochs: override the demo's number of training epochs.
        train_models: False evaluates the baselines only (no training).

    Returns:
        The :class:`Evaluation` of the test split; ``results["config"]`` also holds ``demo_seconds``,
        ``train_seconds`` (per model) and ``demo_train`` (the training settings used).
    """
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="seqnet-demo-") as tmp:
        root = Path(out) if out is not None else Path(tmp)
        data_dir = save_dataset(make_synthetic(places=places, seed=seed), root / "dataset", overwrite=True)
        ds = load_dataset(data_dir)
        logger.info("demo dataset: %d reference / %d query frames, D=%d", len(ds.reference), len(ds.query),
                    ds.query.dim)
        models, seconds = train_demo_models(ds, root, data_dir, device, epochs, seed) if train_models else ({}, {})
        methods = DEMO_METHODS if train_models else [*BASELINES, "hvpr-delta:raw+seqmatch"]
        ev = evaluate(ds.split("test"), EvalConfig(methods=tuple(methods), seq_len=DEMO_SEQ_LEN, device=device), models)
    ev.results["config"].update(demo_seconds=round(time.perf_counter() - t0, 2), train_seconds=seconds,
                                demo_train={**DEMO_TRAIN, **({"epochs": epochs} if epochs else {})})
    return ev
