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


@pytest.mark.parametrize("kw, pattern", [({"kind": "an noy"}, "ANN index kind"), ({"nprobe": 0}, "nprobe"),
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


@pytest.mark.parametrize("spec", ["IVF16,Flat", "HNSW16", "HNSW16,SQ8", "OPQ4,IVF16,PQ4x4", "PCA8,IVF8,Flat"])
def test_any_faiss_factory_string_builds_and_searches(spec):
    from seqnet.search.ann import AnnConfig, build_index, shortlist_recall
    from seqnet.search.ann import search as ann_search
    from seqnet.search.knn import knn

    rng = np.random.default_rng(0)
    x = rng.standard_normal((2000, 16)).astype(np.float32)
    q = x[:50] + 0.01 * rng.standard_normal((50, 16)).astype(np.float32)
    index = build_index(x, AnnConfig(kind=spec, nprobe=16, ef_search=64))
    assert index.ntotal == 2000
    found = ann_search(index, q, 10)[1]
    assert shortlist_recall(found, knn(q, x, 10)[1]) > 0.2  # an approximate but working index
    assert (found[:, 0] == np.arange(50)).mean() > 0.5  # each query's own vector is mostly found first


def test_bad_factory_strings_are_clear_errors():
    from seqnet.core.errors import ConfigError
    from seqnet.search.ann import AnnConfig, build_index, make_index

    with pytest.raises(ConfigError, match="neither an alias"):
        AnnConfig(kind="hnsw 32")
    with pytest.raises(ConfigError, match="FAISS cannot make index 'IVFX,Flat'.*valid: an alias"):
        make_index(16, 1000, AnnConfig(kind="IVFX,Flat"))
    with pytest.raises(ConfigError, match="cannot train"):
        build_index(np.zeros((20, 16), np.float32), AnnConfig(kind="IVF64,PQ4"))
    assert AnnConfig(kind="hnsw").factory(16, 100) == "HNSW32" and AnnConfig().factory(8, 10) == "Flat"
    assert AnnConfig(kind="ivf-pq", pq_m=4, pq_bits=4).factory(16, 4000) == "IVF102,PQ4x4"
