"""Approximate shortlists: every index kind builds, searches, saves and reloads; flat equals exact k-NN."""

from __future__ import annotations

import numpy as np
import pytest

from seqnet.core.errors import CheckpointError, ConfigError
from seqnet.search.ann import ANN_INDEXES, AnnConfig, build_index, load_index, save_index, search, shortlist_recall
from seqnet.search.knn import knn


@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(0)
    centres = rng.standard_normal((40, 16)).astype(np.float32)
    ref = (centres[rng.integers(0, 40, 3000)] + 0.05 * rng.standard_normal((3000, 16))).astype(np.float32)
    query = (ref[:100] + 0.01 * rng.standard_normal((100, 16))).astype(np.float32)
    return ref, query


@pytest.mark.parametrize("kind", list(ANN_INDEXES))
def test_every_kind_finds_most_exact_neighbours(data, kind, tmp_path):
    ref, query = data
    conf = AnnConfig(kind=kind, nlist=20, nprobe=20, pq_m=8, pq_bits=8)
    index = build_index(ref, conf)
    dist, ids = search(index, query, 10)
    _, exact = knn(query, ref, 10)
    rec = shortlist_recall(ids, exact)
    # product quantisation is lossy: within a tight cluster its neighbours are partly arbitrary
    assert rec >= {"flat": 1.0, "ivf-pq": 0.3}.get(kind, 0.8), (kind, rec)
    assert dist.shape == ids.shape == (100, 10) and (np.diff(dist, axis=1) >= -1e-5).all()
    path = save_index(index, tmp_path / "i.faiss")
    again = load_index(path, conf)
    np.testing.assert_array_equal(search(again, query, 10)[1], ids)


def test_flat_distances_equal_exact(data):
    ref, query = data
    dist, ids = search(build_index(ref), query, 5)
    d2, i2 = knn(query, ref, 5)
    np.testing.assert_allclose(dist, d2, rtol=1e-4, atol=1e-4)


def test_deterministic_ivf(data):
    ref, query = data
    a = search(build_index(ref, AnnConfig(kind="ivf-flat", nlist=16, nprobe=2)), query, 5)[1]
    b = search(build_index(ref, AnnConfig(kind="ivf-flat", nlist=16, nprobe=2)), query, 5)[1]
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("kw, pattern", [({"kind": "annoy"}, "ANN index kind"), ({"nprobe": 0}, "nprobe"),
                                         ({"pq_bits": 20}, "pq_bits"), ({"nlist": 0}, "nlist")])
def test_config_errors(kw, pattern):
    with pytest.raises(ConfigError, match=pattern):
        AnnConfig(**kw)


def test_build_errors(data, tmp_path):
    ref, _ = data
    with pytest.raises(ConfigError, match="pq_m dividing D=16"):
        build_index(ref, AnnConfig(kind="ivf-pq", pq_m=5))
    with pytest.raises(ConfigError, match="non-empty"):
        build_index(np.zeros((0, 4)))
    (tmp_path / "bad.faiss").write_text("garbage")
    with pytest.raises(CheckpointError, match="cannot read FAISS index"):
        load_index(tmp_path / "bad.faiss")
