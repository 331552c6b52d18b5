"""VPR-methods-evaluation's image folders (test_dataset.read_images_paths at gmberton/VPR-methods-evaluation
adbb6e2): the list file ``<folder>_images_paths.txt`` beside the folder, in its order, else the sorted recursive
glob of .jpg/.jpeg/.png files; seqnet gives its descriptor rows the same names, or one error."""

from __future__ import annotations

import logging
import os

import numpy as np
import pytest

from seqnet.cli import main
from seqnet.core.errors import DatasetError
from seqnet.data.imagefolders import folder_names
from seqnet.data.io import load_dataset
from seqnet.data.readers import read_names


def _images(folder, names):
    for n in names:
        (folder / n).parent.mkdir(parents=True, exist_ok=True)
        (folder / n).write_bytes(b"")


def test_the_list_file_beside_the_folder_is_followed_in_its_order(tmp_path, caplog):
    db = tmp_path / "database"
    _images(db, ["@0@0@a@.jpg", "@9@0@b@.jpg", "sub/@5@0@c@.png"])
    (tmp_path / "database_images_paths.txt").write_text("sub/@5@0@c@.png\n@9@0@b@.jpg\n@0@0@a@.jpg\n")
    with caplog.at_level(logging.INFO, logger="seqnet"):
        assert read_names(db) == ["sub/@5@0@c@.png", "@9@0@b@.jpg", "@0@0@a@.jpg"]  # listed, not sorted
    assert "database_images_paths.txt (VPR-methods-evaluation's list file" in caplog.text
    (tmp_path / "database_images_paths.txt").write_text("@9@0@b@.jpg\r\n@0@0@a@.jpg")  # str.splitlines, as VME
    assert folder_names(db) == ["@9@0@b@.jpg", "@0@0@a@.jpg"]


def test_png_jpeg_and_upper_case_images_are_found_in_pythons_sorted_order(tmp_path, caplog):
    """sorted() over the full paths: '@' (0x40) < 'B' < 'Z' < '_' < 's', sub-folders in place, '.tif' and
    other files left out, hidden files and folders skipped (glob's '*')."""
    db = tmp_path / "db"
    _images(db, ["@25@0@f@.jpg", "sub/@20@0@c@.png", "@10@0@b@.JPG", "@30@0@d@.jpeg", "Z/@1@1@z@.PNG",
                 "B.Jpeg", "_x.jpg", "@40@0@e@.tif", "notes.txt", ".@50@0@hidden@.jpg", ".cache/@6@0@h@.jpg",
                 "sub/deeper/@2@2@y@.jpg", "sub.jpg/@3@3@w@.jpg"])
    (db / "dir.jpg").mkdir()  # a folder named like an image is not an image
    expected = ["@10@0@b@.JPG", "@25@0@f@.jpg", "@30@0@d@.jpeg", "B.Jpeg", "Z/@1@1@z@.PNG", "_x.jpg",
                "sub.jpg/@3@3@w@.jpg", "sub/@20@0@c@.png", "sub/deeper/@2@2@y@.jpg"]
    full = [os.path.join(str(db), n) for n in expected]
    assert full == sorted(full)  # the order is Python's over the full paths
    with caplog.at_level(logging.INFO, logger="seqnet"):
        assert folder_names(db) == expected
    assert "9 image names by sorted(glob('**/*'))" in caplog.text


@pytest.mark.parametrize("line, match", [
    ("../outside.jpg", r"line 2: '\.\./outside\.jpg' leads outside"),
    ("/etc/passwd", r"line 2: '/etc/passwd' leads outside"),
    ("a\x00.jpg", r"line 2: 'a\\x00\.jpg' is not a relative path inside"),
    ("missing.jpg", r"line 2: 'missing\.jpg' is not a file in"),
    ("", r"line 2: '' is empty or starts or ends with whitespace"),
    (" a.jpg", r"line 2: ' a\.jpg' is empty or starts or ends with whitespace"),
    ("sub", r"line 2: 'sub' is not a file in"),
])
def test_a_list_line_that_is_not_a_file_inside_the_folder_is_refused_naming_its_line(tmp_path, line, match):
    db = tmp_path / "db"
    _images(db, ["a.jpg", "sub/b.jpg"])
    (tmp_path / "outside.jpg").write_bytes(b"")
    (tmp_path / "db_images_paths.txt").write_text(f"a.jpg\n{line}\nsub/b.jpg\n")
    with pytest.raises(DatasetError, match=match):
        folder_names(db)


def test_list_files_that_cannot_be_followed_are_refused(tmp_path):
    db = tmp_path / "db"
    _images(db, ["a.jpg"])
    (tmp_path / "db_images_paths.txt").write_text("")
    with pytest.raises(DatasetError, match="the image list file is empty"):
        folder_names(db)
    os.symlink(tmp_path / "outside.jpg", db / "link.jpg")
    (tmp_path / "outside.jpg").write_bytes(b"")
    (tmp_path / "db_images_paths.txt").write_text("link.jpg\n")
    with pytest.raises(DatasetError, match="leads outside .* through a symbolic link"):
        folder_names(db)
    (tmp_path / "db_images_paths.txt").unlink()
    (db / "_images_paths.txt").write_text("a.jpg\n")  # VME reads it only for 'db/' (a trailing slash)
    with pytest.raises(DatasetError, match="only when the folder is given with a trailing '/'"):
        folder_names(db)
    (db / "_images_paths.txt").unlink()
    (db / "link.jpg").unlink()
    (db / "a.jpg").rename(db / "a.tif")
    with pytest.raises(DatasetError, match="no .jpg/.jpeg/.png images under it"):
        folder_names(db)


def _vme_case(tmp_path, listed: bool):
    """A VME layout: database (6 images, one .png in a sub-folder) and queries folders; descriptors saved in
    the list file's order, which differs from the sorted one."""
    rng = np.random.default_rng(0)
    db_names = [f"@{500000 + 10 * (5 - i):.2f}@4400000.00@17@T@{i}@.jpg" for i in range(6)]
    db_names[4] = "sub/" + db_names[4].replace(".jpg", ".png")
    q_names = [f"@{500000 + 10 * i + 1:.2f}@4400000.00@17@T@q{i}@.jpg" for i in range(3)]
    _images(tmp_path / "database", db_names)
    _images(tmp_path / "queries", q_names)
    if listed:
        (tmp_path / "database_images_paths.txt").write_text("\n".join(db_names) + "\n")
    np.save(tmp_path / "db.npy", rng.standard_normal((6, 4)).astype(np.float32))
    np.save(tmp_path / "q.npy", rng.standard_normal((3, 4)).astype(np.float32))
    return ["-q", "dataset", "from-utm-names", "--ref-desc", str(tmp_path / "db.npy"), "--ref-names",
            str(tmp_path / "database"), "--query-desc", str(tmp_path / "q.npy"), "--query-names",
            str(tmp_path / "queries"), "--radius", "25", "--out", str(tmp_path / "out")], db_names


def test_from_utm_names_gives_the_descriptor_rows_the_listed_names_and_positions(tmp_path):
    argv, db_names = _vme_case(tmp_path, listed=True)
    assert main(argv) == 0
    ds = load_dataset(tmp_path / "out")
    assert ds.reference.names == db_names
    np.testing.assert_array_equal(ds.reference.positions[:, 0], [500050, 500040, 500030, 500020, 500010, 500000])


def test_a_count_mismatch_names_the_folder_rule_and_hints_at_the_list_file(tmp_path, capsys):
    argv, _ = _vme_case(tmp_path, listed=False)
    (tmp_path / "database" / "extra@1@2@.png").write_bytes(b"")
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "7 names for 6 descriptors" in err and "database_images_paths.txt (VPR-methods-evaluation's list" in err
    (tmp_path / "database_images_paths.txt").write_text("@500050.00@4400000.00@17@T@0@.jpg\n")
    assert main(argv) == 2
    assert "the names are the lines of" in capsys.readouterr().err
