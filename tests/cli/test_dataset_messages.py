"""What ``seqnet dataset ...`` says: errors name the subcommand, from-images says what it wrote in one line,
an impossible ``--pca`` is refused before any image is described, a ``[D, N]`` descriptor array is named."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from seqnet.cli import main


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    root = tmp_path_factory.mktemp("imgs")
    rng = np.random.default_rng(2)
    for side in ("ref", "qry"):
        (root / side).mkdir()
        for i in range(10):
            Image.fromarray((rng.random((8, 8)) * 255).astype(np.uint8)).save(root / side / f"{side}{i:02d}.png")
    return root


def from_images(folder, out, *extra):
    return main(["dataset", "from-images", str(folder / "ref"), str(folder / "qry"), "--method", "pixels", "--patch",
                 "0", "--frame-aligned", "--radius", "1", "--out", str(out), *extra])


def test_from_images_says_what_it_wrote_in_one_line(folder, tmp_path, capsys):
    assert from_images(folder, tmp_path / "ds") == 0
    out, err = capsys.readouterr()
    wrote = [line for line in (out + err).splitlines() if "wrote" in line]
    assert wrote == [f"wrote dataset {tmp_path / 'ds'} (reference 10, query 10 images): ground truth frames, radius 1 "
                     f"frames, descriptors pixels, D=64 (provenance {wrote[0].rsplit(' ', 1)[-1][:-1]})"]
    assert from_images(folder, tmp_path / "named", "--name", "sw") == 0
    assert f"wrote dataset {tmp_path / 'named'} (reference 10, query 10 images, named 'sw'): " in capsys.readouterr()[0]


def test_from_images_names_the_views_beside_the_doubled_d(folder, tmp_path, capsys, caplog):
    """With --views the lines say them: D=128 of 8x8 pixels is two views of 64, not a wrong size."""
    import logging

    with caplog.at_level(logging.INFO, logger="seqnet"):
        assert from_images(folder, tmp_path / "dv", "--views", "raw,equalize") == 0
    out = capsys.readouterr()[0]
    assert "descriptors pixels, views raw,equalize, D=128 (provenance " in out
    said = [r.getMessage() for r in caplog.records]
    assert "describing 10 reference images (pixels, views raw,equalize)" in said
    assert "describing 10 query images (pixels, views raw,equalize)" in said
    for side in ("ref", "qry"):  # from-csv's line too
        assert main(["-q", "describe", str(folder / side), "--method", "pixels", "--patch", "0", "--views",
                     "raw,equalize", "--out", str(tmp_path / f"{side}.npy")]) == 0
    for side in ("ref", "qry"):
        (tmp_path / f"{side}.csv").write_text("name,frame\n" + "".join(f"{side}{i:02d}.png,{i}\n" for i in range(10)))
    assert main(["dataset", "from-csv", "--ref-csv", str(tmp_path / "ref.csv"), "--ref-desc", str(tmp_path / "ref.npy"),
                 "--query-csv", str(tmp_path / "qry.csv"), "--query-desc", str(tmp_path / "qry.npy"), "--radius",
                 "1", "--out", str(tmp_path / "dc")]) == 0
    assert "images, descriptors pixels, views raw,equalize, D=128, radius 1 frames" in capsys.readouterr()[0]


def test_errors_name_the_subcommand_and_pca_is_checked_first(folder, tmp_path, capsys):
    args = ["--split", "train=0:4", "--split", "test=4:10", "--pca", "20"]
    assert from_images(folder, tmp_path / "p", *args) == 2
    err = capsys.readouterr().err
    assert err == ("seqnet dataset from-images: error: --pca 20: the 'train' split has 14 frames, and a PCA fitted "
                   "on them has at most 13 axes (N frames centred on their mean span N - 1) (hint: --pca 4 or a larger "
                   "train split)\n")  # no image described
    assert from_images(folder, tmp_path / "p", *args[:-1], "14") == 2  # as many as the frames: one axis arbitrary
    assert "--pca 14: the 'train' split has 14 frames, and a PCA fitted on them has at most 13 axes" in \
        capsys.readouterr().err and not (tmp_path / "p").exists()
    assert from_images(folder, tmp_path / "p", *args[:-1], "13") == 0
    capsys.readouterr()
    assert main(["dataset", "check", str(tmp_path / "none")]) == 2
    assert capsys.readouterr().err.startswith("seqnet dataset check: error: ")


def test_a_transposed_descriptor_array_is_named(tmp_path, capsys):
    (tmp_path / "r.csv").write_text("name,frame\n" + "".join(f"r{i}.png,{i}\n" for i in range(5)))
    np.save(tmp_path / "rT.npy", np.random.default_rng(0).random((8, 5)).astype(np.float32))  # [D, N]
    np.save(tmp_path / "q.npy", np.random.default_rng(1).random((5, 8)).astype(np.float32))
    argv = ["dataset", "from-csv", "--ref-csv", str(tmp_path / "r.csv"), "--ref-desc", str(tmp_path / "rT.npy"),
            "--query-csv", str(tmp_path / "r.csv"), "--query-desc", str(tmp_path / "q.npy"), "--radius", "1",
            "--out", str(tmp_path / "ds")]
    assert main(argv) == 2
    assert capsys.readouterr().err == (f"seqnet dataset from-csv: error: {tmp_path / 'r.csv'}: 5 rows but "
                                       f"{tmp_path / 'rT.npy'} holds 8 descriptors; transposed? the array is [8, 5]; "
                                       "seqnet expects [N, D] (one row per image)\n")


def test_from_csv_with_constant_positions_is_warned(tmp_path, capsys):
    rng = np.random.default_rng(4)
    for side in ("r", "q"):
        (tmp_path / f"{side}.csv").write_text("name,easting,northing\n" + "".join(f"{side}{i}.png,500000,6000000\n"
                                                                                 for i in range(6)))
        np.save(tmp_path / f"{side}.npy", rng.random((6, 4)).astype(np.float32))
    argv = ["dataset", "from-csv", "--ref-csv", str(tmp_path / "r.csv"), "--ref-desc", str(tmp_path / "r.npy"),
            "--query-csv", str(tmp_path / "q.csv"), "--query-desc", str(tmp_path / "q.npy"), "--radius", "25",
            "--out", str(tmp_path / "ds")]
    assert main(argv) == 0
    assert ("ds: all 6 reference and 6 query positions lie within 0 metres of each other, inside the radius 25: "
            "every reference is within the radius of every query, so R@K is 1 trivially") in capsys.readouterr().err


@pytest.mark.parametrize(("splits", "said"), [
    (["train=0:5", "train=5:10"], "--split train=5:10: the split train is given twice (first --split train=0:5); "
                                  "give each split once"),
    (["all=0:5", "test=5:10"], "--split all=0:5: the name 'all' is reserved: all means every query (eval --split "
                               "all, train --train-split all): this split could never be chosen; give the split "
                               "another name"),
    (["NONE=0:5"], "--split NONE=0:5: the name 'NONE' is reserved: none means no validation"),
])
def test_split_names_given_twice_or_reserved_are_refused(folder, tmp_path, capsys, splits, said):
    """The last of two splits of one name won silently, and a split named ``all`` was shadowed by every query
    (with a warning that it shared queries with test): refused in one line, nothing written."""
    args = [a for s in splits for a in ("--split", s)]
    assert from_images(folder, tmp_path / "ds", *args) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"seqnet dataset from-images: error: {said}") and len(err.splitlines()) == 1, err
    assert not (tmp_path / "ds").exists()


def test_split_names_other_than_train_val_test_are_warned(folder, tmp_path, capsys):
    assert from_images(folder, tmp_path / "ds", "--split", "Train=0:5", "--split", "holdout=5:10") == 0
    err = capsys.readouterr().err
    assert "--split Train=0:5: split names are case-sensitive; did you mean train? seqnet's commands use the splits " \
           "train, val and test by default" in err
    assert "--split holdout=5:10: seqnet's commands use the splits train, val and test by default (train trains on " \
           "train and chooses the epoch on val; eval, index and localize take test), so holdout is used only where " \
           "a command names it (--split holdout, --train-split holdout)" in err
    assert from_images(folder, tmp_path / "ok", "--split", "train=0:4", "--split", "val=4:6", "--split",
                       "test=6:10") == 0
    assert "--split" not in capsys.readouterr().err
