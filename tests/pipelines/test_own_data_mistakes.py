"""``seqnet dataset from-images`` and ``dataset check`` on likely mistakes (docs/own_data.md): frame-aligned
folders that cannot pair up are refused before any image is described (one line, exit 2); the query folder
being the reference folder and splits sharing queries are one warning line each."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from PIL import Image

from seqnet.cli import main


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    root = tmp_path_factory.mktemp("mistakes")
    rng = np.random.default_rng(1)
    for side, n in (("ref", 12), ("qry", 12)):
        (root / side).mkdir()
        for i in range(n):
            img = (rng.random((8, 16)) * 255).astype(np.uint8)
            Image.fromarray(img).save(root / side / f"f{i:03d}.png")
    return root


def build(folders, out, ref="ref", qry="qry", *extra):
    return main(["dataset", "from-images", str(folders / ref), str(folders / qry), "--method", "pixels", "--patch",
                 "0", "--frame-aligned", "--radius", "1", "--out", str(out), *extra])


def test_frame_aligned_folders_that_cannot_pair_up_are_refused(folders, tmp_path, capsys):
    short = tmp_path / "short"
    shutil.copytree(folders / "qry", short)
    (short / "f011.png").unlink()
    assert build(folders, tmp_path / "ds", "ref", str(short)) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("seqnet dataset from-images: error: --frame-aligned: query frame i is the place of "
                          "reference frame i, but the reference has 12 images and the query 11")
    shutil.copy(short / "f010.png", short / "f099.png")  # as many, but f005 missing: every later frame shifted
    (short / "f005.png").unlink()
    shutil.copy(short / "f010.png", short / "f098.png")
    assert build(folders, tmp_path / "ds", "ref", str(short)) == 2
    assert "reference image 5 is 'f005.png' but query image 5 is 'f006.png'" in capsys.readouterr().err
    assert not (tmp_path / "ds").exists()


def test_the_reference_as_query_and_shared_queries_are_warned(folders, tmp_path, capsys):
    splits = ["--split", "train=0:6", "--split", "test=4:12"]
    assert build(folders, tmp_path / "same", "ref", "ref", *splits) == 0
    err = capsys.readouterr().err
    assert "same: the query images are the reference images (identical descriptors, row for row)" in err
    assert "same: splits train (queries 0:6) and test (queries 4:12) share 2 queries" in err
    assert main(["dataset", "check", str(tmp_path / "same")]) == 0
    assert "every metric is trivially perfect" in capsys.readouterr().err


def test_fit_on_a_split_of_queries_against_the_whole_reference(folders, tmp_path, capsys, monkeypatch):
    """``--fit-on train`` with ``--split train=A:B`` (no reference range): fitted on the whole reference and the
    train queries (was an internal KeyError)."""
    from seqnet.pipelines import from_images

    fits = []
    real = from_images.make_describer
    monkeypatch.setattr(from_images, "make_describer", lambda conf, fit, *a, **k: (fits.append(list(fit)),
                                                                                     real(conf, fit, *a, **k))[1])
    assert build(folders, tmp_path / "ds", "ref", "qry", "--dim", "4", "--fit-on", "train", "--split", "train=0:6",
                 "--split", "test=6:12") == 0
    assert sorted(p.parent.name for p in fits[0]) == ["qry"] * 6 + ["ref"] * 12


@pytest.mark.parametrize("split", ["test", "Test"])
def test_fit_on_the_test_split_is_refused(folders, tmp_path, capsys, split):
    """``--fit-on test`` fitted the PCA / clusters on the test queries silently (``--pca`` refuses it): refused in
    one line naming the flag, nothing written."""
    assert build(folders, tmp_path / "ds", "ref", "qry", "--dim", "4", "--fit-on", split, "--split", "train=0:6",
                 "--split", f"{split}=6:12") == 2
    err = capsys.readouterr().err
    assert err.splitlines()[-1] == (f"seqnet dataset from-images: error: --fit-on {split}: fitting the describer's PCA "
                                    "/ NetVLAD clusters on the test split's images makes its numbers optimistic; fit "
                                    "on the reference (the default) or on a train split (--fit-on train)")
    assert not (tmp_path / "ds").exists()


def test_reference_and_query_images_of_two_sizes_are_refused_with_the_resize(folders, tmp_path, capsys):
    """Two cameras: each folder has one size, but not the same one; described natively the descriptors differ in
    length. The error names both sizes and the --resize that fixes it, before any image is described."""
    big = tmp_path / "big"
    big.mkdir()
    for p in sorted((folders / "qry").iterdir()):
        Image.open(p).resize((32, 16)).save(big / p.name)
    assert build(folders, tmp_path / "ds", "ref", str(big)) == 2
    err = capsys.readouterr().err
    assert err == ("seqnet dataset from-images: error: the first reference image is 16x8 and the first query image "
                   "32x16 (native size): their descriptors would differ in length; give --resize 16x8\n")
    assert not (tmp_path / "ds").exists()
    assert build(folders, tmp_path / "ds", "ref", str(big), "--resize", "16x8") == 0
