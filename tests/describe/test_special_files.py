"""FIFOs, devices and sockets are refused without being opened (opening a FIFO waits for a writer)."""

from __future__ import annotations

import os
import threading

import pytest

from seqnet.cli import main
from seqnet.core.errors import DatasetError, ImageError
from seqnet.data.readers import read_descriptor_file
from seqnet.describe.images import read_image
from seqnet.security.inputs import special_file


@pytest.fixture
def fifo(tmp_path):
    path = tmp_path / "frame.png"
    os.mkfifo(path)
    return path


def _within(seconds, fn):
    """Run ``fn`` in a thread; fail if it does not return within ``seconds`` (a hang)."""
    out = {}
    t = threading.Thread(target=lambda: out.setdefault("r", fn()), daemon=True)
    t.start()
    t.join(seconds)
    assert not t.is_alive(), "hung"
    return out.get("r")


def test_special_files_are_told_apart(tmp_path, fifo):
    (tmp_path / "x.png").write_bytes(b"")
    assert special_file(fifo) == "FIFO" and special_file("/dev/null") == "character device"
    assert special_file(tmp_path / "x.png") is None and special_file(tmp_path) is None
    assert special_file(tmp_path / "missing") is None


def test_a_fifo_image_is_refused_not_opened(fifo):
    def read():
        with pytest.raises(ImageError, match="is a FIFO, not a regular file"):
            read_image(fifo)
        return True

    assert _within(10, read)


def test_a_list_file_naming_a_fifo_does_not_hang_describe(fifo, folder, tmp_path, capsys):
    lst = tmp_path / "list.txt"
    lst.write_text(f"{folder / 'f0.png'}\n{fifo}\n")
    code = _within(60, lambda: main(["describe", str(lst), "--method", "pixels", "--out", str(tmp_path / "d.npy")]))
    assert code == 2 and "is a FIFO" in capsys.readouterr().err
    code = _within(60, lambda: main(["describe", str(lst), "--method", "pixels", "--skip-corrupted",
                                     "--out", str(tmp_path / "d.npy")]))
    assert code == 0


def test_a_fifo_descriptor_file_is_refused(tmp_path):
    path = tmp_path / "d.npy"
    os.mkfifo(path)

    def read():
        with pytest.raises(DatasetError, match="it is a FIFO, not a regular file"):
            read_descriptor_file(path)
        return True

    assert _within(10, read)


def test_a_folder_entry_that_is_no_image_file_is_refused_not_skipped(folder):
    """Skipping it would shift every later frame (frame-aligned ground truth): it is refused, named."""
    from seqnet.describe.images import list_images

    os.symlink(folder / "missing.png", folder / "f05a.png")  # a broken link among the images
    with pytest.raises(ImageError, match="f05a.png is a broken link, not an image file"):
        list_images(folder)
    os.unlink(folder / "f05a.png")
    os.mkfifo(folder / "f05b.png")
    with pytest.raises(ImageError, match="f05b.png is a FIFO"):
        list_images(folder)  # stat only: a FIFO is never opened
    os.unlink(folder / "f05b.png")
    (folder / "notes.txt").write_text("not an image: ignored")
    assert len(list_images(folder)) == 10


def test_names_a_names_file_cannot_keep_are_refused_when_made(tmp_path):
    from seqnet.data.readers import check_names

    with pytest.raises(DatasetError, match="starts or ends with whitespace"):
        check_names(["a.png", " a.png"], "images")
    from seqnet.describe.images import list_images

    d = tmp_path / "imgs"
    d.mkdir()
    from PIL import Image

    for n in ("a.png", " a.png"):
        Image.new("RGB", (4, 4)).save(d / n)
    with pytest.raises(ImageError, match="whitespace"):
        list_images(d)
