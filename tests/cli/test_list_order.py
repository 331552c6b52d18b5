"""Image list files written in text order (``ls`` / ``sorted()`` of unpadded frame numbers: img_0, img_1, img_10,
img_11, img_2, ...) scramble the route: the build, ``seqnet dataset check`` and ``seqnet eval`` say so in one line
with the fix, where frame-index ground truth (--frame-aligned, --positives) shows nothing else."""

from __future__ import annotations

import logging

import pytest
from conftest import image_folder

from seqnet.cli import main

N = 12
TEXT_ORDER = "is in text order, not by the numbers in its names: 'ref/img_10.png' comes before 'ref/img_2.png'"


@pytest.fixture(scope="module")
def lists(tmp_path_factory):
    root = tmp_path_factory.mktemp("lists")
    for seed, side in enumerate(("ref", "qry")):
        image_folder(root / side, N, seed, stem="img_")
        names = [f"{side}/img_{i}.png" for i in range(N)]
        (root / f"{side}_ls.txt").write_text("".join(f"{n}\n" for n in sorted(names)))  # as `ls` writes them
        (root / f"{side}_v.txt").write_text("".join(f"{n}\n" for n in names))  # as `ls -v` writes them
    return root


def _build(root, out, order, caplog):
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        assert main(["dataset", "from-images", str(root / f"ref_{order}.txt"), str(root / f"qry_{order}.txt"),
                     "--method", "pixels", "--patch", "0", "--frame-aligned", "--radius", "1", "--out",
                     str(out)]) == 0
    return [r.getMessage() for r in caplog.records if "text order" in r.getMessage()]


def test_a_list_in_text_order_is_said_at_build_check_and_eval(lists, tmp_path, caplog):
    said = _build(lists, tmp_path / "ds", "ls", caplog)
    assert len(said) == 2 and TEXT_ORDER in said[0] and "hint: list the images by number: ls -v" in said[0]
    assert said[0].startswith(f"image list {lists / 'ref_ls.txt'} is in text order")
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        assert main(["dataset", "check", str(tmp_path / "ds")]) == 0
    checked = [r.getMessage() for r in caplog.records if "text order" in r.getMessage()]
    assert len(checked) == 2 and checked[0].startswith(f"ds: the query traverse {TEXT_ORDER.replace('ref/', 'qry/')}")
    assert checked[1].startswith(f"ds: the reference traverse {TEXT_ORDER}")
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        assert main(["eval", "--dataset", str(tmp_path / "ds"), "--method", "single,raw+seqmatch", "--seq-len",
                     "3", "--ks", "1"]) == 0
    assert any(r.getMessage().startswith(f"ds: the reference traverse {TEXT_ORDER}") for r in caplog.records)


def test_a_list_in_number_order_is_silent(lists, tmp_path, caplog):
    assert _build(lists, tmp_path / "ds", "v", caplog) == []
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        assert main(["dataset", "check", str(tmp_path / "ds")]) == 0
    assert not [r for r in caplog.records if "text order" in r.getMessage()]
