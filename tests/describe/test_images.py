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


def test_webp_and_gif_are_images_and_other_files_are_counted(tmp_path, caplog):
    """.webp and .gif are formats seqnet reads: listed (they were skipped silently); what is left out is said,
    hidden files (macOS ._* AppleDouble files) among it."""
    import logging

    caplog.set_level(logging.INFO, logger="seqnet")
    for name in ("a1.png", "a2.webp", "a3.gif", "a4.PNG"):
        _save(tmp_path / name)
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "._a1.png").write_bytes(b"\x00\x05\x16\x07 AppleDouble")  # not an image, though named .png
    (tmp_path / ".DS_Store").write_bytes(b"\x00")
    lst = list_images(tmp_path)
    assert lst.names == ["a1.png", "a2.webp", "a3.gif", "a4.PNG"]
    imgs, skipped = load_images(lst.paths)
    assert imgs.shape == (4, 8, 12, 3) and skipped == []
    said = [r.getMessage() for r in caplog.records if "left out" in r.getMessage()]
    assert len(said) == 1 and "1 file of other extensions (.txt: 1)" in said[0] and "2 hidden files" in said[0]
    caplog.clear()
    (tmp_path / "notes.txt").unlink()
    for hidden in (tmp_path / "._a1.png", tmp_path / ".DS_Store"):
        hidden.unlink()
    list_images(tmp_path)
    assert not [r for r in caplog.records if "left out" in r.getMessage()]  # nothing left out: nothing said


def test_list_file_with_a_bom_and_windows_backslashes(tmp_path, caplog):
    """Notepad's "UTF-8 with BOM": the BOM is not part of the first path; Windows paths (``a\\x.png``) are read
    with '/' where only that is a file, said in one line; a Windows absolute path is refused at its line with
    the hint; a list with '/' says nothing."""
    (tmp_path / "a").mkdir()
    _save(tmp_path / "a" / "x.png")
    _save(tmp_path / "y.png")
    lf = tmp_path / "list.txt"
    lf.write_text("\ufeffa/x.png\r\ny.png\r\n", encoding="utf-8")
    with caplog.at_level("INFO", logger="seqnet"):
        assert list_images(lf).names == ["a/x.png", "y.png"]
    assert not caplog.records
    lf.write_text("a\\x.png\r\ny.png\r\n")
    with caplog.at_level("INFO", logger="seqnet"):
        lst = list_images(lf)
    assert lst.names == ["a/x.png", "y.png"] and lst.paths[0] == tmp_path / "a" / "x.png"
    assert "paths written with backslashes (Windows) read with '/'" in caplog.text
    lf.write_text("y.png\nC:\\data\\a\\x.png\n")
    with pytest.raises(ImageError, match=r"list.txt, line 2: image not found: 'C:\\data\\a\\x.png' \(nor with '/' "
                                         r"for its backslashes\); hint: a Windows path\?"):
        list_images(lf)


def test_duplicate_line_in_a_list_file_names_both_lines(tmp_path):
    _save(tmp_path / "x.png")
    _save(tmp_path / "y.png")
    lf = tmp_path / "list.txt"
    lf.write_text("x.png\n# c\ny.png\nx.png\n")
    with pytest.raises(ImageError, match=r"list.txt, line 4: 'x.png' is listed again \(first on line 1\).*remove "
                                         r"the duplicate line\)$"):
        list_images(lf)


def test_a_list_file_in_cp1252_is_told_to_be_saved_as_utf8(tmp_path):
    (tmp_path / "l.txt").write_bytes("røf.png\n".encode("cp1252"))
    with pytest.raises(ImageError, match=r"not UTF-8 text .*; hint: a list in another encoding .*Save it as UTF-8"):
        list_images(tmp_path / "l.txt")
