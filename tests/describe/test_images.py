"""Tests of image listing and loading."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from seqnet.core.errors import ImageError
from seqnet.describe.images import list_images, load_images


def _save(path, h=8, w=12, value=0):
    Image.fromarray(np.full((h, w, 3), value, dtype=np.uint8)).save(path)
    return path


def test_folder_natural_order_and_extensions(tmp_path):
    for name in ("img10.png", "img2.jpg", "img1.bmp"):
        _save(tmp_path / name)
    (tmp_path / "notes.txt").write_text("x")
    lst = list_images(tmp_path)
    assert lst.names == ["img1.bmp", "img2.jpg", "img10.png"]


def test_list_file_relative_to_its_folder(tmp_path):
    (tmp_path / "a").mkdir()
    _save(tmp_path / "a" / "x.png", value=10)
    _save(tmp_path / "y.png", value=20)
    lf = tmp_path / "list.txt"
    lf.write_text("# comment\na/x.png\n\ny.png\n")
    lst = list_images(lf)
    assert lst.names == ["a/x.png", "y.png"]
    imgs, skipped = load_images(lst.paths)
    assert imgs.shape == (2, 8, 12, 3) and skipped == [] and imgs[1, 0, 0, 0] == 20


def test_resize_crop_grey(tmp_path):
    p = _save(tmp_path / "a.png", h=10, w=20)
    imgs, _ = load_images([p], size=(8, 4), crop_bottom=2, grey=True)
    assert imgs.shape == (1, 4, 8) and imgs.dtype == np.uint8
    imgs, _ = load_images([p], crop_bottom=3)
    assert imgs.shape == (1, 7, 20, 3)


def test_empty_folder_and_missing(tmp_path):
    with pytest.raises(ImageError, match="no images in folder"):
        list_images(tmp_path)
    with pytest.raises(ImageError, match="not found"):
        list_images(tmp_path / "nope")


def test_corrupted_image_named_or_skipped(tmp_path):
    good = _save(tmp_path / "a.png")
    bad = tmp_path / "b.png"
    bad.write_bytes(b"\x89PNG garbage")
    trunc = tmp_path / "c.png"
    trunc.write_bytes(good.read_bytes()[:40])
    with pytest.raises(ImageError, match="b.png"):
        load_images([good, bad])
    with pytest.raises(ImageError, match="c.png"):
        load_images([good, trunc])
    imgs, skipped = load_images([good, bad, trunc], skip_corrupted=True)
    assert imgs.shape[0] == 1 and skipped == [1, 2]


def test_mixed_sizes(tmp_path):
    a, b = _save(tmp_path / "a.png", h=8), _save(tmp_path / "b.png", h=9)
    with pytest.raises(ImageError, match=r"b.png has size 12x9"):
        load_images([a, b])
    assert load_images([a, b], size=(6, 4))[0].shape == (2, 4, 6, 3)
