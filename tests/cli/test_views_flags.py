"""``--views`` on the command line: describe records it; where a val choice names its candidates' views, a
--views without --method / --descriptor is refused in one line instead of being ignored."""

from __future__ import annotations

import json

import numpy as np
from PIL import Image

from seqnet.cli import main as cli_main


def test_describe_views_doubles_d_and_is_recorded(tmp_path):
    (tmp_path / "imgs").mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        Image.fromarray(rng.integers(0, 80, (16, 32, 3), dtype=np.uint8)).save(tmp_path / "imgs" / f"{i}.png")
    out = tmp_path / "d.npy"
    assert cli_main(["-q", "describe", str(tmp_path / "imgs"), "--method", "pixels", "--views", "raw,equalize",
                     "--out", str(out)]) == 0
    assert np.load(out).shape == (3, 2 * 32 * 16)
    assert json.loads((tmp_path / "d.provenance.json").read_text())["settings"]["views"] == ["raw", "equalize"]
    assert cli_main(["describe", str(tmp_path / "imgs"), "--method", "pixels", "--views", "raw,blur", "--out",
                     str(tmp_path / "e.npy")]) == 2


def test_views_without_the_descriptor_they_apply_to_are_refused(tmp_path, capsys):
    assert cli_main(["benchmark", "nordland64", "--data", str(tmp_path), "--out", str(tmp_path / "o"), "--views",
                     "raw,equalize"]) == 2
    assert "--views goes with --descriptor" in capsys.readouterr().err
    assert cli_main(["dataset", "from-images", str(tmp_path), str(tmp_path), "--views", "raw,equalize", "--out",
                     str(tmp_path / "ds"), "--frame-aligned", "--radius", "1"]) == 2
    err = capsys.readouterr().err
    assert "--views goes with --method" in err and "hint: --method netvlad --views raw,equalize" in err
