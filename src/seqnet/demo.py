"""The built-in demo: synthetic data → every method → comparison table."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

from .evaluate import Evaluation, evaluate
from .synth import make_synthetic
from .traverse import load_dataset, save_dataset
from .utils import logger

DEMO_METHODS = ["single", "smoothing", "delta", "raw+seqmatch", "delta+seqmatch", "hvpr"]


def run_demo(out: str | Path | None = None, places: int = 1000, seed: int = 0, device: str = "auto") -> Evaluation:
    """Generate a synthetic dataset, save it in the directory format, reload it and evaluate.

    Args:
        out: directory to keep the dataset and results in (default: a temporary directory).
        places: number of places along the synthetic route.
        seed: random seed.
        device: torch device.
    """
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="seqnet-demo-") as tmp:
        root = Path(out) if out is not None else Path(tmp)
        data_dir = save_dataset(make_synthetic(places=places, seed=seed), root / "dataset", overwrite=True)
        ds = load_dataset(data_dir)
        logger.info("demo dataset: %d reference / %d query frames, D=%d", len(ds.reference), len(ds.query), ds.query.dim)
        config: dict[str, Any] = {"methods": DEMO_METHODS, "seq_len": 5, "device": device}
        ev = evaluate(ds.split("test"), config)
    ev.results["config"]["demo_seconds"] = round(time.perf_counter() - t0, 2)
    return ev
