"""Tests of the SeqSLAM "pixels" descriptor."""

from __future__ import annotations

import numpy as np
import pytest

from seqnet.core.errors import ConfigError
from seqnet.describe.pixels import patch_normalise, pixels_descriptor, to_grey


def test_shape_norm_and_dtype(rng):
    imgs = rng.integers(0, 256, size=(5, 32, 64, 3), dtype=np.uint8)
    d = pixels_descriptor(imgs)
    assert d.shape == (5, 32 * 64) and d.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, rtol=1e-5)


def test_resize_and_grey_input(rng):
    imgs = rng.random((3, 40, 80)).astype(np.float32)
    assert pixels_descriptor(imgs, size=(32, 16)).shape == (3, 512)


def test_patches_are_zero_mean_unit_variance(rng):
    grey = rng.random((2, 16, 24))
    out = patch_normalise(grey, patch=8)
    blocks = out.reshape(2, 2, 8, 3, 8)
    np.testing.assert_allclose(blocks.mean(axis=(2, 4)), 0.0, atol=1e-5)
    np.testing.assert_allclose(blocks.std(axis=(2, 4)), 1.0, atol=1e-4)


def test_ragged_edge_patches_and_flat_patches():
    grey = np.zeros((1, 10, 12), dtype=np.float32)
    grey[0, :8, :8] = np.arange(64).reshape(8, 8)
    out = patch_normalise(grey, patch=8)
    assert out.shape == (1, 10, 12) and np.isfinite(out).all()
    assert np.all(out[0, 8:, :] == 0) and np.all(out[0, :, 8:] == 0)  # flat patches become zero
    assert abs(out[0, :8, :8].mean()) < 1e-5


def test_invariant_to_brightness_and_contrast_per_patch(rng):
    imgs = rng.random((2, 16, 16)).astype(np.float32)
    np.testing.assert_allclose(pixels_descriptor(imgs), pixels_descriptor(imgs * 0.5 + 0.2), atol=1e-5)


def test_deterministic_and_grey_matches_rgb_of_equal_channels(rng):
    grey = rng.integers(0, 256, size=(2, 16, 16), dtype=np.uint8)
    rgb = np.repeat(grey[..., None], 3, axis=-1)
    np.testing.assert_allclose(pixels_descriptor(grey), pixels_descriptor(rgb), atol=1e-5)
    np.testing.assert_array_equal(pixels_descriptor(rgb), pixels_descriptor(rgb))


def test_bad_shapes_raise():
    with pytest.raises(ConfigError, match="channels"):
        to_grey(np.zeros((1, 4, 4, 2)))
    with pytest.raises(ConfigError, match=r"\[N, H, W\]"):
        to_grey(np.zeros((4, 4)))
