"""The built-in demo: synthetic data → train S_L and S_1 → every method → comparison table.

The demo trains with its own fast settings (:class:`DemoConfig`: Adam, a larger learning rate, at
most 40 epochs with early stopping after 8 without a better val R@1) instead of the paper's (SGD
lr 1e-4 for up to 200 epochs), so that the whole demo runs in seconds on two CPU cores.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

from ..core.config import Config, check_bool, check_int
from ..core.log import logger
from ..core.stage import Written
from ..data.io import load_dataset, save_dataset
from ..data.synth import SynthConfig, make_synthetic
from ..data.traverse import Dataset
from ..eval.config import EvalConfig
from ..eval.score import score
from ..security.files import write_json_atomic
from ..security.locks import locked
from ..sequence.checkpoints import load_model
from ..train import TrainConfig, train
from .outputs import check_outputs_of, write_outputs

BASELINES = ("single", "smoothing", "delta", "raw+seqmatch", "delta+seqmatch")
LEARNED = ("seqnet", "s1+seqmatch", "hvpr")  # hvpr: shortlist with S_L, re-rank by SeqMatch on S_1
MODEL_FREE_HVPR = "hvpr-delta:raw+seqmatch"
KIND = "demo"  # the command, as the output folder's record names it
DEMO_TRAIN = TrainConfig(optimizer="adam", lr=1e-3, weight_decay=0.0, epochs=40, patience=8, out_dims=256)


@dataclasses.dataclass(frozen=True)
class DemoConfig(Config):
    """Settings of the demo.

    Attributes:
        places: places along the synthetic route.
        seed: random seed (data and training).
        seq_len: L of S_L, the evaluation windows and SeqMatch.
        w: the S_L temporal filter width.
        train_models: False evaluates the baselines (and the model-free HVPR) only.
        train: the demo's fast training settings (S_1 uses them with L = w = 1).
        device: torch device.
    """

    places: int = 2000
    seed: int = 0
    seq_len: int = 5
    w: int = 3
    train_models: bool = True
    train: TrainConfig = DEMO_TRAIN
    device: str = "auto"

    def __post_init__(self) -> None:
        self._set("places", check_int("places", self.places, 100))
        self._set("seed", check_int("seed", self.seed, 0))
        self._set("seq_len", check_int("seq_len", self.seq_len, 2))
        self._set("w", check_int("w", self.w, 1, self.seq_len))
        self._set("train_models", check_bool("train_models", self.train_models))

    @property
    def methods(self) -> tuple[str, ...]:
        """The methods compared."""
        return (*BASELINES, *LEARNED) if self.train_models else (*BASELINES, MODEL_FREE_HVPR)

    def model_configs(self) -> dict[str, TrainConfig]:
        """The training settings of S_L ("seqnet") and S_1 ("s1")."""
        base = self.train.merge(device=self.device, seed=self.seed)
        return {"seqnet": base.merge(seq_len=self.seq_len, w=self.w), "s1": base.merge(seq_len=1, w=1)}


def train_demo_models(ds: Dataset, conf: DemoConfig, root: Path, data_dir: Path) -> tuple[dict[str, Any], dict]:
    """Train S_L and S_1 on ``ds`` (runs in ``root/train_<role>``, new folders; ``data_dir``: where the dataset
    will be, recorded in the runs); returns models by role and seconds per role."""
    models, seconds = {}, {}
    for role, tconf in conf.model_configs().items():
        t0 = time.perf_counter()
        run = train(ds, tconf, root / f"train_{role}", dataset_path=str(data_dir))
        models[role] = load_model(run.out_dir / "best.pt")
        seconds[role] = round(time.perf_counter() - t0, 2)
        logger.debug("demo: trained %s in %.1f s (best val R@1 %.3f at epoch %d)", role, seconds[role],
                     run.best_score, run.best_epoch)
    return models, seconds


def demo_outputs(conf: DemoConfig) -> tuple[str, ...]:
    """What the demo writes into its output folder."""
    return ("dataset", *(f"train_{r}" for r in (conf.model_configs() if conf.train_models else ())), "results.json")


def main(conf: DemoConfig, out: str | Path, overwrite: bool = False) -> Written:
    """Generate a synthetic dataset in ``out/dataset``, train S_L and S_1 (``out/train_seqnet``,
    ``out/train_s1``), evaluate every method on the test split; writes ``out/results.json`` (results,
    resolved config, timings) and returns its path.

    These outputs replace only what an earlier demo wrote there (anything else, a dataset or training run
    of your own included, is refused before any work, unless ``overwrite``), and appear together: they are
    made in a temporary folder beside ``out`` and swapped in with the other files of ``out`` kept."""
    t0 = time.perf_counter()
    root = Path(out)
    results: dict[str, Any] = {}
    with locked(root):
        check_outputs_of(root, demo_outputs(conf), KIND, "demo's outputs", overwrite)
        write_outputs(root, KIND, "demo's outputs", lambda tmp: results.update(run_demo(conf, tmp, root, t0)),
                      overwrite)
    return Written(root / "results.json", results)


def run_demo(conf: DemoConfig, tmp: Path, root: Path, t0: float) -> dict[str, Any]:
    """The demo's outputs written into ``tmp`` (to become ``root``); its results."""
    data_dir = save_dataset(make_synthetic(SynthConfig(places=conf.places, seed=conf.seed)), tmp / "dataset")
    ds = load_dataset(data_dir)
    logger.info("demo dataset: %d reference / %d query frames, D=%d", len(ds.reference), len(ds.query),
                ds.query.dim)
    models, seconds = train_demo_models(ds, conf, tmp, root / "dataset") if conf.train_models else ({}, {})
    ev = score(ds.split("test"), EvalConfig(methods=conf.methods, seq_len=conf.seq_len, device=conf.device),
                  models)
    ev.results["config"].update(demo=conf.to_dict(), demo_seconds=round(time.perf_counter() - t0, 2),
                                train_seconds=seconds)
    write_json_atomic(tmp / "results.json", ev.results)
    return ev.results
