"""Shared test fixtures: tiny synthetic data and the location of ../shared/data."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import torch

torch.set_num_threads(2)

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("SEQNET_SHARED_DATA", REPO.parent / "shared" / "data"))


def shared_data(sub: str) -> Path:
    """Path of ``../shared/data/<sub>``; skips the test with a message when it is absent."""
    path = SHARED_DATA / sub
    if not path.exists():
        pytest.skip(f"shared data not found: {path} (set SEQNET_SHARED_DATA or place ../shared/data beside the repo)")
    return path


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(0)


@pytest.fixture(scope="session")
def synth_dataset():
    """A small synthetic dataset (UTM positions, splits, sequence bounds)."""
    from seqnet.data.synth import make_synthetic

    return make_synthetic(places=200, dim=16, seed=1)


@pytest.fixture
def synth_dir(tmp_path, synth_dataset):
    """The small synthetic dataset saved in the directory format."""
    from seqnet.data.io import save_dataset

    return save_dataset(synth_dataset, tmp_path / "ds")


@pytest.fixture
def map_models(synth_dataset, tmp_path):
    """Checkpoint paths of a random S_L (L=4, w=2) and S_1 made for ``synth_dataset``'s descriptors."""
    from seqnet.sequence.checkpoints import save_checkpoint
    from seqnet.sequence.model import SeqNet

    torch.manual_seed(0)
    paths = []
    for name, (seq_len, w) in {"sl": (4, 2), "s1": (1, 1)}.items():
        model = SeqNet(16, 12, seq_len, w)
        model.provenance = synth_dataset.reference.provenance
        paths.append(save_checkpoint(tmp_path / f"{name}.pt", model))
    return paths


def image_folder(d, n: int = 10, seed: int = 0, stem: str = "f"):
    """A folder ``d`` of ``n`` random 32×16 RGB PNG images ``<stem>0.png`` … (made here)."""
    from PIL import Image

    rng = np.random.default_rng(seed)
    d.mkdir()
    for i in range(n):
        Image.fromarray(rng.integers(0, 256, size=(16, 32, 3), dtype=np.uint8)).save(d / f"{stem}{i}.png")
    return d


@pytest.fixture
def folder(tmp_path):
    """A folder of ten random 32×16 RGB PNG images ``f0.png`` … ``f9.png``."""
    return image_folder(tmp_path / "imgs")


def pytest_collection_modifyitems(config, items):
    """Tests marked ``cuda`` are skipped, with the reason, where torch sees no CUDA device."""
    if torch.cuda.is_available():
        return
    skip = pytest.mark.skip(reason="needs a CUDA device (none here); benchmarks/gpu_check.sh runs these on a GPU")
    for item in items:
        if "cuda" in item.keywords:
            item.add_marker(skip)
