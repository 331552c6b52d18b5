"""Descriptor rows sharing a common offset far beyond their spread (seqnet.data.sanity.values, and the same check
of seqnet.knn / seqmatch / hvpr): after L2 normalisation every row points the same way and float32 distances lose
what tells places apart, without a word (single R@1 0.993 -> 0.747 at an offset 1000 times the spread, 0.013 at
10000; the hostile own-data test of 2026-12-05)."""

from __future__ import annotations

import logging

import numpy as np
import pytest

import seqnet
from seqnet.core.tensors import NARROW_SPREAD, direction_spread
from seqnet.data.sanity import dataset_warnings
from seqnet.data.traverse import Dataset, Traverse


def route(n: int = 300, d: int = 64, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Reference and query descriptors of one route (place i of both alike, neighbouring places correlated)."""
    rng = np.random.default_rng(seed)
    places = rng.standard_normal((n, d))
    for i in range(1, n):
        places[i] = 0.7 * places[i - 1] + 0.3 * places[i] * 3 ** 0.5
    return places + 0.6 * rng.standard_normal((n, d)), places + 0.6 * rng.standard_normal((n, d))


def make(ref: np.ndarray, qry: np.ndarray) -> Dataset:
    pos = np.arange(len(ref), dtype=float)[:, None]
    return Dataset(Traverse(ref.astype(np.float32), pos, name="reference"),
                   Traverse(qry.astype(np.float32), pos.copy(), name="query"), 2.0, name="d")


def test_direction_spread_against_a_loop():
    rng = np.random.default_rng(1)
    x = rng.standard_normal((37, 5)) + 3.0
    x[4] = 0  # a zero row is left out, as a search leaves it unmatched
    rows = [r / np.linalg.norm(r) for r in x if np.linalg.norm(r) > 0]
    mean = np.mean(rows, axis=0)
    naive = np.sqrt(np.mean([np.sum((r - mean) ** 2) for r in rows]))
    assert direction_spread(x) == pytest.approx(naive, rel=1e-12)
    assert direction_spread(x.astype(np.float32)) == pytest.approx(naive, rel=1e-5)
    assert np.isnan(direction_spread(x[:1])) and np.isnan(direction_spread(np.zeros((5, 3))))
    assert direction_spread(np.ones((6, 4))) == 0.0


@pytest.mark.parametrize("offset, said", [(0, False), (10, False), (1000, True), (1e4, True)])
def test_a_common_offset_is_said_at_build_and_by_check(offset, said):
    ref, qry = route()
    lines = [line for line in dataset_warnings(make(ref + offset, qry + offset)) if "point nearly" in line]
    assert bool(lines) == said
    if said:
        assert lines[0].startswith("d: the descriptors point nearly the same way once L2-normalised")
        assert "x - m" in lines[0]


def test_real_descriptors_are_not_flagged():
    """Real describers' rows spread far above the threshold: patch-normalised and raw grey pixels of Nordland."""
    from pathlib import Path

    from PIL import Image

    folder = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "nordland64" / "summer"
    if not folder.is_dir():
        pytest.skip(f"{folder} is absent (the shared Nordland64 data)")
    files = sorted(folder.glob("*.png"))[:300]
    grey = np.stack([np.asarray(Image.open(f).convert("L"), dtype=np.float32).ravel() for f in files])
    assert direction_spread(grey) > 30 * NARROW_SPREAD  # 0.45 measured: raw 0..255 values, no centring
    ref, qry = route()
    assert direction_spread(ref) > 0.9 and direction_spread(qry) > 0.9


def test_the_search_functions_say_it_once(caplog, monkeypatch):
    from seqnet.core import log

    monkeypatch.setattr(log, "_SAID", set())  # a process in which no warn_once line was said yet
    ref, qry = route()
    r, q = (ref + 1000).astype(np.float32), (qry + 1000).astype(np.float32)
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        seqnet.knn(q, r, 1, normalize=True)
        seqnet.knn(q, r, 1, normalize=True)
        seqnet.knn(qry.astype(np.float32), ref.astype(np.float32), 1, normalize=True)
    lines = [rec.getMessage() for rec in caplog.records if "point nearly" in rec.getMessage()]
    assert len(lines) == 1 and lines[0].startswith("knn: the query rows point nearly the same way")
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        seqnet.knn(q, r, 1, normalize=False)  # ranked as given, unchecked
    assert not [rec for rec in caplog.records if "point nearly" in rec.getMessage()]


def test_eval_says_it_of_a_dataset_built_before(tmp_path, capsys):
    """A dataset written without the check (or before it) is told at evaluation, as the other sanity lines."""
    from seqnet.cli import main
    from seqnet.data.io import save_dataset

    ref, qry = route(120, 16)
    path = save_dataset(make(ref + 1000, qry + 1000), tmp_path / "ds")
    assert main(["eval", "--dataset", str(path), "--method", "single", "--split", "all"]) == 0
    err = capsys.readouterr().err
    assert err.count("the descriptors point nearly the same way") == 1
