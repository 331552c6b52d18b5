"""Decoding one image as an untrusted input: only seqnet's raster formats, PIL's bomb check an error, and a
damaged file of any format one ImageError naming it (shown escaped)."""

from __future__ import annotations

import io

import numpy as np
import pytest
from conftest import mutated
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from PIL import Image

from seqnet.cli import main
from seqnet.core.errors import ImageError
from seqnet.describe import DescribeConfig, describe_images
from seqnet.describe.images import list_images
from seqnet.security.pictures import FORMATS, read_image

EPS = b"%!PS-Adobe-3.0 EPSF-3.0\n%%BoundingBox: 0 0 16 16\n0 0 moveto 16 16 lineto stroke\nshowpage\n"


def test_only_seqnet_raster_formats_are_tried(tmp_path):
    """An EPS file named .png: PIL alone identifies it as EPS (and would run Ghostscript to load it); seqnet
    tries only its raster formats and refuses it."""
    f = tmp_path / "x.png"
    f.write_bytes(EPS)
    with Image.open(f) as im:
        assert im.format == "EPS"
    with pytest.raises(ImageError, match=r"cannot read image .*x.png: not an image of a format seqnet reads \(PNG, "):
        read_image(f)


@pytest.mark.parametrize("fmt", FORMATS)
def test_every_format_of_the_table_reads(tmp_path, fmt):
    rng = np.random.default_rng(0)
    f = tmp_path / f"x.{fmt.lower()}"
    Image.fromarray(rng.integers(0, 256, (8, 12, 3), dtype=np.uint8)).save(f, fmt)
    assert read_image(f).shape == (8, 12, 3)


def test_pil_bomb_check_stays_on_and_is_one_error(tmp_path, monkeypatch):
    f = tmp_path / "x.png"
    Image.fromarray(np.zeros((16, 16, 3), np.uint8)).save(f)
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 200)  # 256 pixels: PIL's warning, as an error
    with pytest.raises(ImageError, match=r"x.png is too large to decode safely \(Image size \(256 pixels\) exceeds"):
        read_image(f)
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 100)  # more than twice: PIL's error
    with pytest.raises(ImageError, match=r"too large to decode safely"):
        read_image(f)
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 10**6)
    with pytest.raises(ImageError, match=r"declares 16x16 pixels, more than the limit of 100"):
        read_image(f, max_pixels=100)


def test_names_are_shown_escaped(tmp_path):
    f = tmp_path / "a\x1b]0;owned\x07.png"
    f.write_bytes(b"\x89PNG\r\n\x1a\n broken")
    with pytest.raises(ImageError) as e:
        read_image(f)
    assert "\x1b" not in str(e.value) and "a\\x1b]0;owned\\x07.png" in str(e.value)
    assert list_images(tmp_path).names == ["a\x1b]0;owned\x07.png"]  # kept, only shown escaped


def test_describing_no_images_is_a_clear_error():
    for conf in (DescribeConfig(), DescribeConfig(method="gem"), DescribeConfig(dim=4)):
        with pytest.raises((ImageError, ValueError), match=r"no images to (describe|fit)"):
            describe_images([], conf)


@pytest.mark.parametrize("batch", ["4", "32"])
def test_one_frame_of_another_size_is_named_with_both_sizes(tmp_path, capsys, batch):
    """A 128x64 frame among 64x32 ones at --resize native: the message names that frame, both sizes and the
    --resize that fixes it, whether it is in the first batch or a later one."""
    rng = np.random.default_rng(0)
    (tmp_path / "imgs").mkdir()
    for i in range(10):
        shape = (64, 128, 3) if i == 5 else (32, 64, 3)
        Image.fromarray(rng.integers(0, 256, shape, dtype=np.uint8)).save(tmp_path / "imgs" / f"f{i}.png")
    assert main(["describe", str(tmp_path / "imgs"), "--method", "pixels", "--resize", "native", "--batch-size",
                 batch, "--out", str(tmp_path / "d.h5")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "f5.png has size 128x64 but the images before it" in err and "have 64x32" in err
    assert "hint: --resize 64x32" in err


def _sources() -> list[bytes]:
    rng = np.random.default_rng(0)
    img = Image.fromarray(rng.integers(0, 256, (12, 16, 3), dtype=np.uint8))
    out = []
    for fmt in FORMATS:
        b = io.BytesIO()
        img.save(b, fmt)
        out.append(b.getvalue())
    b = io.BytesIO()
    Image.fromarray((rng.random((8, 8)) * 65535).astype(np.uint16)).save(b, "PNG")
    return [*out, b.getvalue()]


SOURCES = _sources()


@pytest.mark.filterwarnings("ignore::UserWarning")  # PIL's own, on damaged TIFF tags
@settings(max_examples=250, deadline=None, suppress_health_check=list(HealthCheck))
@given(data=st.data())
def test_fuzzed_images_decode_or_are_one_error(tmp_path_factory, data):
    f = tmp_path_factory.mktemp("img") / "x.img"
    f.write_bytes(data.draw(mutated(data.draw(st.sampled_from(SOURCES)), max_flips=6)))
    try:
        out = read_image(f)
    except ImageError:
        return
    assert out.dtype == np.uint8 and out.ndim == 3 and out.shape[2] == 3


@pytest.mark.parametrize("orientation", range(1, 9))
def test_exif_orientation_is_applied_as_viewers_do(tmp_path, orientation):
    from PIL import ImageOps

    rng = np.random.default_rng(orientation)
    stored = Image.fromarray(rng.integers(0, 256, (12, 20, 3), dtype=np.uint8))
    exif = Image.Exif()
    exif[0x0112] = orientation
    stored.save(tmp_path / "a.png", exif=exif)
    shown = np.asarray(ImageOps.exif_transpose(Image.open(tmp_path / "a.png")).convert("RGB"))  # what viewers show
    np.testing.assert_array_equal(read_image(tmp_path / "a.png"), shown)
    assert read_image(tmp_path / "a.png").shape[:2] == ((20, 12) if orientation >= 5 else (12, 20))


def test_a_phone_jpeg_stored_sideways_reads_upright(tmp_path):
    rng = np.random.default_rng(0)
    upright = np.repeat(np.repeat(rng.integers(0, 256, (4, 8, 3), dtype=np.uint8), 8, 0), 8, 1)  # 64x32, smooth
    exif = Image.Exif()
    exif[0x0112] = 6  # "rotate 90 CW to view"
    Image.fromarray(upright).transpose(Image.Transpose.ROTATE_90).save(tmp_path / "p.jpg", quality=98, exif=exif)
    Image.fromarray(upright).save(tmp_path / "plain.jpg", quality=98)
    got, plain = read_image(tmp_path / "p.jpg"), read_image(tmp_path / "plain.jpg")
    assert got.shape == plain.shape == (32, 64, 3)
    assert np.abs(got.astype(int) - plain.astype(int)).mean() < 3


def _png16_rgb(path, a):
    """A 16-bit RGB PNG (colour type 2, bit depth 16) of ``a`` (uint16 [H, W, 3]): PIL cannot write one."""
    import struct
    import zlib

    h, w, _ = a.shape
    raw = b"".join(b"\x00" + a[y].astype(">u2").tobytes() for y in range(h))

    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)

    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 2, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))
    return path


def test_8_bit_values_in_a_16_bit_file_read_as_8_bit_said_once_per_folder(tmp_path, caplog):
    import logging

    caplog.set_level(logging.WARNING, logger="seqnet")
    rng = np.random.default_rng(0)
    grey8 = [rng.integers(0, 256, (12, 20)).astype(np.uint8) for _ in range(3)]
    rgb8 = rng.integers(0, 256, (12, 20, 3)).astype(np.uint8)
    for i, g in enumerate(grey8):
        Image.fromarray(g.astype(np.uint16)).save(tmp_path / f"g{i}.png")  # uint8 data saved as uint16
    _png16_rgb(tmp_path / "c.png", rgb8.astype(np.uint16))
    for i, g in enumerate(grey8):
        np.testing.assert_array_equal(read_image(tmp_path / f"g{i}.png", grey=True), g)
    np.testing.assert_array_equal(read_image(tmp_path / "c.png"), rgb8)
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 1 and "g0.png is 16-bit" in said[0] and "values are 0..255 only" in said[0], said
    assert "read as 8-bit" in said[0] and "without another line" in said[0]


def test_genuine_16_bit_images_are_scaled_and_silent(tmp_path, caplog):
    import logging

    caplog.set_level(logging.WARNING, logger="seqnet")
    rng = np.random.default_rng(1)
    g, c = rng.integers(0, 256, (12, 20)).astype(np.uint8), rng.integers(0, 256, (12, 20, 3)).astype(np.uint8)
    Image.fromarray(g.astype(np.uint16) * 257).save(tmp_path / "g.png")
    _png16_rgb(tmp_path / "c.png", c.astype(np.uint16) * 257)
    _png16_rgb(tmp_path / "black.png", np.zeros((4, 4, 3), np.uint16))
    np.testing.assert_array_equal(read_image(tmp_path / "g.png", grey=True), g)
    np.testing.assert_array_equal(read_image(tmp_path / "c.png"), c)
    assert not read_image(tmp_path / "black.png").any()
    assert caplog.records == []
