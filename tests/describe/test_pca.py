"""Tests of PCA / whitening."""

from __future__ import annotations

import numpy as np
import pytest

from seqnet.core.errors import CheckpointError, ConfigError
from seqnet.describe.pca import PCA, fit_pca


@pytest.mark.parametrize("n,d", [(200, 16), (10, 50)])
def test_round_trip_and_shapes(tmp_path, rng, n, d):
    x = rng.normal(size=(n, d)).astype(np.float32)
    pca = fit_pca(x, dims=5, whiten=True)
    y = pca.transform(x)
    assert y.shape == (n, 5) and y.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(y, axis=1), 1.0, rtol=1e-5)
    loaded = PCA.load(pca.save(tmp_path / "pca.npz"))
    np.testing.assert_array_equal(loaded.transform(x), y)
    assert loaded.whiten and loaded.dims == 5


def test_components_orthonormal_and_whitened_unit_variance(rng):
    x = rng.normal(size=(500, 8)) * np.array([5, 4, 3, 2, 1, 1, 1, 1])
    pca = fit_pca(x, dims=4, whiten=True)
    np.testing.assert_allclose(pca.components @ pca.components.T, np.eye(4), atol=1e-5)
    y = pca.transform(x, l2=False)
    np.testing.assert_allclose(y.var(axis=0, ddof=1), 1.0, rtol=1e-3)
    assert abs(pca.components[0, 0]) > 0.9  # largest-variance axis first


def test_unwhitened_full_rank_preserves_distances(rng):
    x = rng.normal(size=(30, 6))
    y = fit_pca(x, dims=6, l2=False).transform(x)
    dx = np.linalg.norm(x[:, None] - x[None], axis=-1)
    dy = np.linalg.norm(y[:, None] - y[None], axis=-1)
    np.testing.assert_allclose(dx, dy, atol=1e-4)


def test_errors(tmp_path, rng):
    with pytest.raises(ConfigError, match=r"--dim 20: the PCA is fitted on 10 images, .* at most 9 axes"):
        fit_pca(rng.normal(size=(10, 8)), dims=20)
    with pytest.raises(ConfigError, match=r"--dim 9: a PCA of 8-D descriptors keeps between 1 and 8 dimensions"):
        fit_pca(rng.normal(size=(20, 8)), dims=9)
    with pytest.raises(ConfigError, match=r"--dim 0: .* between 1 and 8"):
        fit_pca(rng.normal(size=(20, 8)), dims=0)
    pca = fit_pca(rng.normal(size=(10, 8)), dims=2)
    with pytest.raises(ConfigError, match=r"\[N, 8\]"):
        pca.transform(np.zeros((3, 7)))
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(CheckpointError, match="bad.npz"):
        PCA.load(bad)


def test_provenance_tag(tmp_path, rng):
    from seqnet.describe.pca import read_tag

    pca = fit_pca(rng.normal(size=(20, 6)), dims=2)
    assert read_tag(pca.save(tmp_path / "plain.npz")) is None
    tagged = pca.save(tmp_path / "tagged.npz", tag='{"output": "ref.h5"}')
    assert read_tag(tagged) == '{"output": "ref.h5"}' and PCA.load(tagged).dims == 2
    (tmp_path / "user.npz").write_text("my pca\n")
    assert read_tag(tmp_path / "user.npz") is None and read_tag(tmp_path / "missing.npz") is None


def test_n_rows_span_at_most_n_minus_1_axes(rng):
    x = rng.normal(size=(6, 50))
    with pytest.raises(ConfigError) as e:  # 6 centred rows: rank 5, a 6th axis would be noise of the SVD
        fit_pca(x, dims=6)
    assert str(e.value) == ("--dim 6: the PCA is fitted on 6 images, and a PCA fitted on them has at most 5 axes "
                            "(N images centred on their mean span N - 1) (hint: --dim 2 or more images to fit it on "
                            "(--fit-on))")
    assert np.linalg.matrix_rank(x - x.mean(axis=0)) == 5
    pca = fit_pca(x, dims=5)
    np.testing.assert_allclose(pca.components @ pca.components.T, np.eye(5), atol=1e-5)
    assert fit_pca(rng.normal(size=(9, 8)), dims=8).dims == 8  # N - 1 = D: every axis


def test_the_dataset_pca_check_shares_the_message():
    from seqnet.describe.pca import check_fit_rows
    from seqnet.pipelines.pca import check_fit_frames

    with pytest.raises(ConfigError) as e:
        check_fit_frames(14, 14)
    assert str(e.value) == ("--pca 14: the 'train' split has 14 frames, and a PCA fitted on them has at most 13 axes "
                            "(N frames centred on their mean span N - 1) (hint: --pca 4 or a larger train split)")
    check_fit_frames(13, 14)
    check_fit_rows(3, 4, "--dim", "x", "y")
