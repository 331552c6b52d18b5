"""Every image mode is converted from its own range or refused: 16-bit and float greyscale, palette,
CMYK, alpha — against the 8-bit image they were made from."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from seqnet.core.errors import ImageError
from seqnet.describe.images import read_image


@pytest.fixture
def grey8(rng):
    return rng.integers(0, 256, (12, 20)).astype(np.uint8)


def test_16_bit_png_equals_its_8_bit_original(tmp_path, grey8):
    Image.fromarray(grey8.astype(np.uint16) * 257).save(tmp_path / "g16.png")  # 0..255 -> 0..65535
    assert Image.open(tmp_path / "g16.png").mode.startswith("I")
    np.testing.assert_array_equal(read_image(tmp_path / "g16.png", grey=True), grey8)
    rgb = read_image(tmp_path / "g16.png")
    assert rgb.shape == (12, 20, 3) and (rgb[..., 0] == grey8).all()


@pytest.mark.parametrize("scale", [1 / 255, 1.0])  # floats in [0, 1] and in [0, 255]
def test_float_tiff_is_read_from_its_range(tmp_path, grey8, scale):
    Image.fromarray(grey8.astype(np.float32) * np.float32(scale)).save(tmp_path / "f.tiff")
    assert Image.open(tmp_path / "f.tiff").mode == "F"
    np.testing.assert_array_equal(read_image(tmp_path / "f.tiff", grey=True), grey8)


def test_float_outside_known_ranges_and_nan_are_refused(tmp_path):
    Image.fromarray(np.full((4, 4), 1000.0, np.float32)).save(tmp_path / "big.tiff")
    with pytest.raises(ImageError, match=r"values in \[1000, 1000\]"):
        read_image(tmp_path / "big.tiff")
    bad = np.zeros((4, 4), np.float32)
    bad[0, 0] = np.nan
    Image.fromarray(bad).save(tmp_path / "nan.tiff")
    with pytest.raises(ImageError, match="NaN"):
        read_image(tmp_path / "nan.tiff")


def test_palette_cmyk_and_alpha_are_converted(tmp_path, rng):
    rgb = rng.integers(0, 256, (10, 10, 3)).astype(np.uint8)
    Image.fromarray(rgb).convert("P", palette=Image.ADAPTIVE, colors=256).save(tmp_path / "p.png")
    pal = Image.open(tmp_path / "p.png")
    assert pal.mode == "P"
    np.testing.assert_array_equal(read_image(tmp_path / "p.png"), np.asarray(pal.convert("RGB")))
    Image.fromarray(rgb).convert("CMYK").save(tmp_path / "c.jpg", quality=100)
    assert np.abs(read_image(tmp_path / "c.jpg").astype(int) - rgb).mean() < 12  # JPEG, CMYK round trip
    rgba = np.dstack([rgb, np.zeros((10, 10), np.uint8)])  # fully transparent: the colours are kept
    Image.fromarray(rgba).save(tmp_path / "a.png")
    np.testing.assert_array_equal(read_image(tmp_path / "a.png"), rgb)
