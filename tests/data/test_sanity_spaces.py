"""A query whose descriptors are not comparable with the reference's (seqnet.data.sanity.spaces): another model (a
rotated basis) or a PCA fitted on each traverse is said at build, by dataset check and at eval; one describer on
both sides, even across a strong appearance change, stays silent."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from seqnet.data.io import save_dataset
from seqnet.data.positives import Positives
from seqnet.data.sanity import dataset_warnings
from seqnet.data.sanity.spaces import (
    FOREIGN_SHARE,
    foreign_spaces,
    own_pca,
    own_place_share,
    route_share,
    separate_pcas,
)
from seqnet.data.traverse import Dataset, Traverse

SHARED = Path(os.environ.get("SEQNET_SHARED_DATA", Path(__file__).resolve().parents[3] / "shared" / "data"))


def route(n: int = 120, d: int = 32, change: float = 0.6, seed: int = 0, query=None, **kw) -> Dataset:
    """Places 10 m apart along a line, each looking like the one before (a random walk); each side sees a place as
    its vector plus noise of ``change`` (a season); ``query``: a function applied to the query's descriptors
    (another model)."""
    rng = np.random.default_rng(seed)
    place = np.cumsum(rng.standard_normal((n, d)), axis=0) * 0.5
    ref = (place + change * rng.standard_normal((n, d))).astype(np.float32)
    qry = (place + change * rng.standard_normal((n, d))).astype(np.float32)
    qry = qry if query is None else query(qry).astype(np.float32)
    pos = np.c_[10.0 * np.arange(n), np.zeros(n)]
    return Dataset(Traverse(ref, pos, name="reference"), Traverse(qry, pos + 0.5, name="query"), 12.0, name="d", **kw)


def rotated(x: np.ndarray) -> np.ndarray:
    q, _ = np.linalg.qr(np.random.default_rng(9).standard_normal((x.shape[1], x.shape[1])))
    return x @ q


def self_pca(x: np.ndarray) -> np.ndarray:
    """The query reduced by its own PCA, the reference (below) by another: axes reordered and sign-flipped."""
    c = x - x.mean(axis=0)
    return c @ np.linalg.svd(c, full_matrices=False)[2].T


def test_another_model_is_said_with_its_causes_and_hint():
    [line] = [w for w in dataset_warnings(route(query=rotated)) if "comparable" in w]
    assert line.startswith("d: the query's descriptors do not look comparable with the reference's: for the median "
                           "query, ")
    assert "descriptors made by two different models, a PCA fitted on each traverse separately" in line
    assert line.endswith("fit one PCA on both sides and apply it to each (seqnet describe --dim, or seqnet train "
                         "--pca), and preprocess both alike")


def test_one_describer_across_a_strong_change_is_silent():
    for change in (0.3, 0.6, 1.0):
        assert foreign_spaces(route(change=change)) is None
        assert own_place_share(route(change=change)) < FOREIGN_SHARE
    assert foreign_spaces(route(query=rotated)) is not None


def test_a_pca_per_traverse_is_said():
    ds = route(d=16, change=0.3)
    c = ds.reference.descriptors - ds.reference.descriptors.mean(axis=0)
    ref = (c @ np.linalg.svd(c, full_matrices=False)[2].T).astype(np.float32)
    flipped = self_pca(ds.query.descriptors)
    flipped[:, ::2] *= -1  # SVD's signs are arbitrary per traverse
    ds = Dataset(ds.reference.with_descriptors(ref), ds.query.with_descriptors(flipped.astype(np.float32)), 12.0,
                 name="d")
    assert own_place_share(ds) > FOREIGN_SHARE and foreign_spaces(ds) is not None


def naive_share(ds: Dataset, clear: float) -> float:
    """The median share, one query and one reference at a time (every row: ``samples`` beyond the sizes)."""
    unit = [t.descriptors / np.linalg.norm(t.descriptors, axis=1, keepdims=True) for t in (ds.query, ds.reference)]
    shares = []
    for i in range(len(ds.query)):
        if ds.positives is not None:
            pos = ds.positives.of(i)
            if not len(pos):
                continue
            own = int(pos[len(pos) // 2])
            others = [j for j in range(len(ds.reference)) if min(abs(j - p) for p in pos) > clear * len(pos)]
        else:
            gaps = np.linalg.norm(ds.reference.positions - ds.query.positions[i], axis=1)
            own = int(gaps.argmin())
            if gaps[own] > ds.radius:
                continue
            others = [j for j in range(len(ds.reference)) if gaps[j] > clear * ds.radius]
        if len(others) >= 10:
            d_own = np.linalg.norm(unit[0][i] - unit[1][own])
            shares.append(np.mean([np.linalg.norm(unit[0][i] - unit[1][j]) < d_own for j in others]))
    return float(np.median(shares))


@pytest.mark.parametrize("explicit", [False, True])
def test_share_vs_a_loop(explicit):
    ds = route(n=130, query=rotated)
    if explicit:  # each query's place and its neighbours, one query with none
        lists = [sorted({max(i - 1, 0), i, min(i + 1, 129)}) if i != 7 else [] for i in range(130)]
        ds = Dataset(ds.reference, ds.query, 12.0, positives=Positives.from_lists(lists), name="d")
    assert abs(own_place_share(ds, samples=500) - naive_share(ds, 3)) < 1e-9


def test_unrelated_rows_say_nothing():
    """Noise on both sides (a test's random descriptors, shuffled frames) is no route: not two spaces of one."""
    rng = np.random.default_rng(1)
    ds = route()
    noise = Dataset(ds.reference.with_descriptors(rng.standard_normal((120, 32)).astype(np.float32)),
                    ds.query.with_descriptors(rng.standard_normal((120, 32)).astype(np.float32)), 12.0, name="d")
    assert own_place_share(noise) > FOREIGN_SHARE and foreign_spaces(noise) is None
    assert route_share(noise.query) > 0.4 and route_share(ds.query) < 0.1


def test_too_few_rows_or_other_sizes_say_nothing():
    assert foreign_spaces(route(n=15, query=rotated)) is None
    far = route(query=rotated)
    lost = Dataset(far.reference, Traverse(far.query.descriptors, far.query.positions + 1e6, name="query"), 12.0,
                   name="d")
    assert foreign_spaces(lost) is None  # no query has its place in the reference: nothing to compare


def test_said_by_dataset_check_and_at_eval(tmp_path):
    save_dataset(route(query=rotated), tmp_path / "ds")
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2] / "src")}
    for cmd in (["dataset", "check", str(tmp_path / "ds")],
                ["eval", "--dataset", str(tmp_path / "ds"), "--method", "single", "--json", str(tmp_path / "r.json")]):
        done = subprocess.run([sys.executable, "-m", "seqnet", *cmd], capture_output=True, text=True, env=env,
                              timeout=300)
        assert "do not look comparable with the reference's" in done.stdout + done.stderr, cmd
    warnings = json.loads((tmp_path / "r.json").read_text())["warnings"]
    assert any("do not look comparable" in w for w in warnings)


@pytest.mark.skipif(not (SHARED / "nordland64").is_dir(), reason="shared data absent (../shared/data/nordland64; "
                    "set SEQNET_SHARED_DATA)")
def test_nordland_summer_winter_pixels_are_one_space(tmp_path):
    from seqnet.describe import DescribeConfig, describe_images

    names = sorted(p.name for p in (SHARED / "nordland64" / "summer").glob("*.png"))[:400:2]
    conf = DescribeConfig(method="pixels", patch=16, size="native")
    sides = [describe_images([SHARED / "nordland64" / s / n for n in names], conf)[0] for s in ("summer", "winter")]
    pos = np.c_[np.arange(len(names), dtype=np.float64)]
    ds = Dataset(Traverse(sides[0], pos, name="reference"), Traverse(sides[1], pos, name="query"), 1.0,
                 position_unit="frames", name="n")
    assert foreign_spaces(ds) is None
    assert foreign_spaces(Dataset(ds.reference, ds.query.with_descriptors(rotated(sides[1])), 1.0,
                                  position_unit="frames", name="n")) is not None


def test_route_share_vs_a_loop():
    t = route(n=70, change=0.8).query
    unit = t.descriptors / np.linalg.norm(t.descriptors, axis=1, keepdims=True)
    shares = []
    for i in range(69):
        others = [j for j in range(70) if abs(j - i) > 3]
        d_next = np.linalg.norm(unit[i] - unit[i + 1])
        shares.append(np.mean([np.linalg.norm(unit[i] - unit[j]) < d_next for j in others]))
    assert abs(route_share(t, samples=500) - np.median(shares)) < 1e-9
    bounds = np.array([[0, 35]] * 35 + [[35, 70]] * 35)  # row 34 ends its sequence: no next row there
    cut = Traverse(t.descriptors, t.positions, seq_bounds=bounds, name="query")
    assert abs(route_share(cut, samples=500) - np.median(shares[:34] + shares[35:])) < 1e-9


def pca_fit(x: np.ndarray, k: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """(mean, components [k, D]) of the rows ``x``."""
    mean = x.mean(axis=0)
    return mean, np.linalg.svd(x - mean, full_matrices=False)[2][:k]


def reduced(ds: Dataset, fit: str) -> Dataset:
    """``ds`` reduced to 16 dims by a PCA fitted on each side (``"each"``), on both, or on the reference."""
    r, q = (np.asarray(t.descriptors, np.float64) for t in (ds.reference, ds.query))
    if fit == "each":
        (mr, cr), (mq, cq) = pca_fit(r), pca_fit(q)
    else:
        mr, cr = pca_fit(np.concatenate([r, q]) if fit == "both" else r)
        mq, cq = mr, cr
    return Dataset(ds.reference.with_descriptors(((r - mr) @ cr.T).astype(np.float32)),
                   ds.query.with_descriptors(((q - mq) @ cq.T).astype(np.float32)), 12.0, name="d")


def test_a_pca_fitted_on_each_side_is_said_before_the_share():
    each = reduced(route(change=0.4), "each")
    [line] = [w for w in dataset_warnings(each) if "PCA" in w]
    assert line.startswith("d: each side's descriptors look reduced by a PCA of its own (the leading columns of each "
                           "side exactly centred, uncorrelated and in decreasing variance)")
    assert "comparable" not in " ".join(dataset_warnings(each))  # one line for one mistake
    for fit in ("both", "reference"):  # one PCA applied to each side: silent
        assert separate_pcas(reduced(route(change=0.4), fit)) is None
        assert dataset_warnings(reduced(route(change=0.4), fit)) == []


def test_own_pca_needs_every_sign_of_one():
    rng = np.random.default_rng(3)
    x = rng.standard_normal((200, 8)) @ rng.standard_normal((8, 8))
    mean, comp = pca_fit(x, 8)
    y = (x - mean) @ comp.T
    assert own_pca(y.astype(np.float32))
    assert not own_pca(x)  # raw rows: correlated, not centred
    assert not own_pca(y[:, ::-1])  # increasing variance: not a PCA's order
    assert not own_pca(y + 0.1 * y.std(axis=0))  # off-centre
    assert not own_pca(y / np.linalg.norm(y, axis=1, keepdims=True))  # L2-normalised after: not exact any more
    assert not own_pca(y[:15])  # too few rows for 8 columns


def test_positives_of_a_place_and_its_neighbours_take_the_place_itself():
    """Positives written p-1, p, p+1 (docs/own_data.md's form): the query's own place is p, not p-1, which can look
    no more like it than any other (hunt 6, F2: 46% said of descriptors that match, 7% by the radius)."""
    rng = np.random.default_rng(4)
    place = rng.standard_normal((150, 32))  # neighbours as unlike as any two places
    side = [Traverse((place + 0.5 * rng.standard_normal(place.shape)).astype(np.float32),
                     np.c_[np.arange(150.0)], name=n) for n in ("reference", "query")]
    lists = [sorted({max(i - 1, 0), i, min(i + 1, 149)}) for i in range(150)]
    explicit = Dataset(*side, 1.0, positives=Positives.from_lists(lists), position_unit="frames", name="d")
    assert own_place_share(explicit) < 0.05


def test_positives_without_a_pair_say_nothing_and_do_not_crash():
    ds = route()
    empty = Dataset(ds.reference, ds.query, 12.0, positives=Positives.from_lists([[] for _ in range(120)]), name="d")
    assert own_place_share(empty) is None and foreign_spaces(empty) is None


def test_a_few_dozen_queries_say_nothing():
    """Below 100 queries the share is noise (one describer on 30-60 Nordland64 frames read up to 0.73): silent."""
    assert foreign_spaces(route(n=60, query=rotated)) is None and foreign_spaces(route(n=120, query=rotated))


def test_the_reference_rows_as_the_query_are_not_two_pcas():
    """One PCA of the reference applied to both sides, the query being those rows reversed (the route driven back
    from the same frames): both sides exactly centred and uncorrelated, yet one PCA (copied_queries says the rest)."""
    ds = reduced(route(change=0.4), "reference")
    rev = Dataset(ds.reference, Traverse(ds.reference.descriptors[::-1], ds.query.positions[::-1], name="query"),
                  12.0, name="d")
    assert own_pca(rev.query.descriptors) and separate_pcas(rev) is None
    assert not own_pca(np.zeros(5))  # not rows: no PCA of its own
