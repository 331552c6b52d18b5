"""``seqnet localize --map --query IMAGES --resize WxH``: query images of another size than the reference images of a
map described at their own (native) size are refused with a hint that works, and described at the map's size."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from PIL import Image

from seqnet.cli import main as cli_main


@pytest.fixture(scope="module")
def native_map(tmp_path_factory):
    """A pixels dataset of Nordland64's 64x32 frames described at their own size, the test query images at that size
    (``small.txt``) and the same images at 128x64 (``big/``)."""
    from conftest import nordland_lists

    root = tmp_path_factory.mktemp("native")
    data, names = nordland_lists(root)
    (root / "small.txt").write_text("".join(f"{data / 'winter' / n}\n" for n in names[40:]))
    (root / "big").mkdir()
    for n in names[40:]:
        Image.open(data / "winter" / n).resize((128, 64)).save(root / "big" / n)
    assert cli_main(["dataset", "from-images", str(root / "ref.txt"), str(root / "query.txt"), "--method", "pixels",
                     "--frame-aligned", "--radius", "1", "--out", str(root / "ds")]) == 0
    return root


def _localize(*args):
    return cli_main(["localize", *map(str, args), "--method", "raw+seqmatch", "--seq-len", "3", "--device", "cpu"])


def _estimates(path):
    return [int(r["estimate"]) for r in csv.DictReader(path.open())]


def test_images_of_another_size_get_a_hint_that_works(native_map, tmp_path, capsys):
    root = native_map
    capsys.readouterr()
    for extra in ([], ["--allow-mismatch"]):  # --allow-mismatch cannot compare D=8192 with D=2048: not suggested
        assert _localize("--map", root / "ds", "--query", root / "big", "--out", tmp_path / "t.csv", *extra) == 2
        err = capsys.readouterr().err
        assert "have D=8192, the map's descriptors D=2048" in err and "hint: --resize 64x32" in err, err
        assert "--allow-mismatch" not in err and len(err.strip().splitlines()) == 1
    small, big = tmp_path / "small.csv", tmp_path / "big.csv"
    assert _localize("--map", root / "ds", "--query", root / "small.txt", "--out", small) == 0
    assert _localize("--map", root / "ds", "--query", root / "big", "--resize", "64x32", "--out", big) == 0
    same = sum(a == b for a, b in zip(_estimates(big), _estimates(small), strict=True))
    assert same >= 17, (_estimates(big), _estimates(small))  # resampled twice (up, then down): close, not equal
    assert _localize("--map", root / "ds", "--query", root / "big", "--resize", "100x50", "--out", big) == 2
    err = capsys.readouterr().err
    assert "--resize 100x50 is not the size of the map's reference images" in err and "hint: --resize 64x32" in err


def test_resize_is_refused_where_it_means_nothing(native_map, tmp_path, capsys):
    from seqnet.data.io import load_dataset

    root = native_map
    frames = tmp_path / "q.npy"
    np.save(frames, np.asarray(load_dataset(root / "ds").query.descriptors[40:]))
    capsys.readouterr()
    assert _localize("--map", root / "ds", "--query", frames, "--resize", "64x32", "--out", tmp_path / "t.csv") == 2
    assert "--resize goes with query images" in capsys.readouterr().err
    assert _localize("--map", root / "ds", "--query", root / "big", "--resize", "native", "--out",
                     tmp_path / "t.csv") == 2
    assert "localize takes WxH" in capsys.readouterr().err
    assert cli_main(["dataset", "from-images", str(root / "ref.txt"), str(root / "query.txt"), "--method", "pixels",
                     "--resize", "32x16", "--frame-aligned", "--radius", "1", "--out", str(tmp_path / "ds16")]) == 0
    capsys.readouterr()
    assert _localize("--map", tmp_path / "ds16", "--query", root / "big", "--resize", "64x32", "--out",
                     tmp_path / "t.csv") == 2
    assert "the map's images were resized to (32, 16) when described" in capsys.readouterr().err
    assert _localize("--map", tmp_path / "ds16", "--query", root / "big", "--out", tmp_path / "t.csv") == 0


def test_one_image_of_another_size_is_named_and_the_frames_done_are_kept(native_map, tmp_path, capsys):
    import json

    root = native_map
    lines = (root / "small.txt").read_text().splitlines()
    (tmp_path / "q").mkdir()
    for k, line in enumerate(lines[:12]):
        im = Image.open(line)
        (im.resize((128, 64)) if k == 8 else im).save(tmp_path / "q" / f"f{k:02d}.png")  # the 9th: another size
    out = tmp_path / "t.csv"
    capsys.readouterr()
    assert _localize("--map", root / "ds", "--query", tmp_path / "q", "--out", out) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "f08.png has size 128x64" in err and "f00.png) have 64x32" in err, err
    assert "--resize 64x32" in err and f"the track of the 8 frames localised before it is written: {out}" in err
    assert len(list(csv.DictReader(out.open()))) == 8
    assert json.loads(out.with_suffix(".json").read_text())["summary"]["partial"] is True
