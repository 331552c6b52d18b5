"""The gallery finds a dataset's images by the names a list file gave them (relative with ``..``, absolute, or
moved: by their last parts) inside ``--images-query`` / ``--images-ref``, and never opens a file outside them."""

from __future__ import annotations

import os

import numpy as np
import pytest

from seqnet.cli import main as cli_main
from seqnet.core.errors import ImageError
from seqnet.data.io import save_dataset


def _png(path, value):
    from PIL import Image

    Image.fromarray(np.full((4, 8, 3), value, np.uint8)).save(path, format="PNG")


@pytest.fixture
def folders(tmp_path, monkeypatch):
    """``data/winter/{a.png (10), sub/b.png (20)}``, ``secret.png`` (200) beside ``data``, ``winter/link.png`` to
    it; the working directory is ``work``."""
    winter = tmp_path / "data" / "winter"
    (winter / "sub").mkdir(parents=True)
    _png(winter / "a.png", 10)
    _png(winter / "sub" / "b.png", 20)
    _png(tmp_path / "secret.png", 200)
    (winter / "link.png").symlink_to(tmp_path / "secret.png")
    (tmp_path / "work").mkdir()
    monkeypatch.chdir(tmp_path / "work")
    return tmp_path


@pytest.fixture
def opened(monkeypatch):
    """The paths the gallery opens (and with which ``follow``)."""
    import seqnet.report.figures as figures

    seen, real = [], figures.open_input
    monkeypatch.setattr(figures, "open_input", lambda p, *a, **k: seen.append((str(p), k.get("follow"))) or
                        real(p, *a, **k))
    return seen


@pytest.mark.parametrize("root", ["../data/winter", "ABS/data/winter", "/"])
@pytest.mark.parametrize("name, value", [
    ("../data/winter/a.png", 10), ("ABS/data/winter/sub/b.png", 20),  # as a list file in work gave them
    ("/moved/elsewhere/a.png", 10), ("../gone/winter/sub/b.png", 20),  # gone since: by their last parts
])
def test_gallery_reads_names_as_a_list_file_gave_them(folders, opened, root, name, value):
    from seqnet.report.figures import gallery_image

    root, name = root.replace("ABS", str(folders)), name.replace("ABS", str(folders))
    if root == "/" and name.startswith(("/moved", "../gone")):
        pytest.skip("a moved file's last parts are looked for in the folder, here /")
    im = gallery_image(root, name)
    assert im.shape == (4, 8, 3) and (im == value).all()
    assert opened and all(follow is False and os.path.realpath(p) == p for p, follow in opened), opened


@pytest.mark.parametrize("name, why", [
    ("../../../../../../../../../../etc/passwd", "leads outside .*winter, to the file /etc/passwd: not read"),
    ("../secret.png", "leads outside .*winter, to the file .*secret.png: not read"),
    ("ABS/secret.png", "to the file .*secret.png: not read"),
    ("link.png", "'link.png' there leads outside .*winter through a symbolic link"),
    ("ABS/data/winter/link.png", "to the file .*secret.png: not read"),
])
def test_gallery_never_opens_a_name_leading_outside(folders, opened, name, why):
    from seqnet.report.figures import GalleryItem, gallery_png

    winter = folders / "data" / "winter"
    _png(winter / "passwd", 0)  # a file of the same name in the folder is another picture: never taken for it
    notes: list[str] = []
    item = GalleryItem(0, ["a.png"], [name.replace("ABS", str(folders))], False, 0.5)
    assert gallery_png(item, winter, winter, notes=notes) is None
    assert len(notes) == 1 and f"not found in {winter}" in notes[0], notes
    import re

    assert re.search(why, notes[0]), notes[0]
    assert not [p for p, _ in opened if "secret" in p or "passwd" in p or "link" in p], opened


def test_a_link_swapped_in_after_the_check_is_not_followed(folders, monkeypatch):
    """The file is opened at its real path without following a link: a link put there after the check is refused
    (O_NOFOLLOW), and the opened file is checked to lie in the folder."""
    import seqnet.report.figures as figures

    winter = folders / "data" / "winter"
    real_open = figures.open_input

    def swap(path, *a, **k):  # the checks saw a.png; a link to the secret replaces it just before the open
        os.replace(winter / "link.png", winter / "a.png")
        return real_open(path, *a, **k)

    monkeypatch.setattr(figures, "open_input", swap)
    with pytest.raises(ImageError, match="a.png is a symbolic link; seqnet does not follow links here"):
        figures.gallery_image(winter, "a.png")


def test_eval_report_shows_pictures_of_a_dataset_from_list_files(folders, capsys):
    """``seqnet eval --report`` on a dataset whose names are the paths its list files gave (query ``../data/q/...``
    relative, reference absolute), as docs/own_data.md builds one: every example has its pictures."""
    from seqnet.data.synth import make_synthetic

    ds = make_synthetic(places=100, dim=8, seed=3)
    for side, t, value in (("q", ds.query, 60), ("r", ds.reference, 30)):
        (folders / "data" / side).mkdir()
        for n in t.names:
            _png(folders / "data" / side / n, value)
    ds.query.names = [f"../data/q/{n}" for n in ds.query.names]
    ds.reference.names = [str(folders / "data" / "r" / n) for n in ds.reference.names]
    save_dataset(ds, "ds")
    assert cli_main(["-q", "eval", "--dataset", "ds", "--method", "single", "--out", "ev", "--report",
                     "--images-query", "../data/q", "--images-ref", str(folders / "data" / "r")]) == 0
    page = open("ev/report.html", encoding="utf-8").read()
    gallery = page.split('<section id="gallery">')[1].split("</section>")[0]
    assert "pictures left out" not in gallery and gallery.count("data:image/png") >= 6, gallery[:2000]
