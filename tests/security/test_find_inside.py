"""``find_inside``: a name kept as a user gave it (``../data/img.png``, an absolute path, a bare name) is found
inside the given folder, and nothing outside that folder is ever returned."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from seqnet.core.errors import ImageError
from seqnet.security.inputs import find_inside


@pytest.fixture
def tree(tmp_path, monkeypatch):
    """``data/winter/{a.png, sub/b.png, link.png -> ../../secret.png, up -> ../..}``, ``secret.png`` and
    ``etc/passwd`` beside it; the working directory is ``work`` (as a list file's folder would be)."""
    winter = tmp_path / "data" / "winter"
    (winter / "sub").mkdir(parents=True)
    for p in (winter / "a.png", winter / "sub" / "b.png", tmp_path / "secret.png"):
        p.write_bytes(p.name.encode())
    (tmp_path / "etc").mkdir()
    (tmp_path / "etc" / "passwd").write_text("root")
    (winter / "link.png").symlink_to(tmp_path / "secret.png")
    (winter / "up").symlink_to(tmp_path)
    (tmp_path / "work").mkdir()
    monkeypatch.chdir(tmp_path / "work")
    return tmp_path


def found(root, name) -> str:
    """The real path ``find_inside`` returns, checked to lie in ``root``."""
    path = os.path.realpath(find_inside(root, name, "image name", ImageError))
    real_root = os.path.realpath(root)
    assert os.path.commonpath([path, real_root]) == real_root and os.path.isfile(path)
    return path


@pytest.mark.parametrize("root", ["../data/winter", "REAL/data/winter", "../data", "/"])
@pytest.mark.parametrize("name", ["../data/winter/a.png", "REAL/data/winter/a.png", "./../data/winter/./a.png"])
def test_a_path_as_a_list_file_gave_it_is_found_in_any_folder_holding_it(tree, root, name):
    root, name = root.replace("REAL", str(tree)), name.replace("REAL", str(tree))
    assert found(root, name) == str(tree / "data" / "winter" / "a.png")


@pytest.mark.parametrize("name, file", [
    ("a.png", "a.png"), ("sub/b.png", "sub/b.png"),  # relative to the folder, as before
    ("/moved/away/a.png", "a.png"), ("../old/winter/sub/b.png", "sub/b.png"),  # gone: by their last parts
])
def test_a_name_whose_path_is_gone_is_found_by_its_last_parts(tree, name, file):
    winter = tree / "data" / "winter"
    assert found(winter, name) == str(winter / file)


def test_a_name_not_there_says_each_name_looked_for(tree):
    with pytest.raises(ImageError, match=r"'old/place/b.png': not found in .*winter \(looked for 'old/place/b.png', "
                                         r"'place/b.png', 'b.png' there; the path as given leads outside .*winter, to "
                                         r".*work/old/place/b.png, where there is no file\)$"):
        find_inside(tree / "data" / "winter", "old/place/b.png", "image name", ImageError)


def test_the_longest_last_parts_win(tree):
    winter = tree / "data" / "winter"
    (winter / "b.png").write_bytes(b"top")
    assert found(winter, "/gone/sub/b.png") == str(winter / "sub" / "b.png")
    assert found(winter, "/gone/b.png") == str(winter / "b.png")


@pytest.mark.parametrize("name, why", [
    ("../etc/passwd", r"the path as given leads outside .*winter, to the file .*etc/passwd: not read"),
    ("../../../../../../../../../../etc/passwd", r"to the file /etc/passwd: not read"),
    ("REAL/etc/passwd", r"to the file .*etc/passwd: not read, nor any file of its name"),
    ("link.png", r"'link.png' there leads outside .*winter through a symbolic link"),
    ("up/secret.png", r"'up/secret.png' there leads outside .* through a symbolic link"),
    ("REAL/data/winter/link.png", r"to the file .*secret.png: not read"),
    ("../secret.png", r"to the file .*secret.png: not read"),
    ("../../nowhere/secret.png", r"looked for 'nowhere/secret.png', 'secret.png' there"),
])
def test_a_name_leading_outside_is_refused_with_what_was_looked_for(tree, name, why):
    winter = tree / "data" / "winter"
    (winter / "passwd").write_text("a file of the same name inside: another file, never taken for it")
    with pytest.raises(ImageError, match=why) as e:
        find_inside(winter, name.replace("REAL", str(tree)), "image name", ImageError)
    assert f"not found in {winter}" in str(e.value)


@pytest.mark.parametrize("name", ["", " ", "a\x00.png", "a\\b.png", None, 3])
def test_what_is_no_path_is_refused(tree, name):
    with pytest.raises(ImageError, match="is not a path to look for"):
        find_inside(tree / "data" / "winter", name, "image name", ImageError)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.sampled_from(["..", ".", "a.png", "b.png", "sub", "up", "link.png", "data", "winter", "etc",
                                 "passwd", "secret.png", "work"]), min_size=1, max_size=6),
       st.booleans(), st.sampled_from(["../data/winter", "../data/winter/sub", "../data"]))
def test_nothing_outside_the_folder_is_ever_returned(tree_once, parts, absolute, root):
    """Whatever the name, what is returned is an existing file whose real path lies in the folder."""
    name = ("/" if absolute else "") + "/".join(parts)
    try:
        path = find_inside(root, name, "image name", ImageError)
    except ImageError:
        return
    real, real_root = os.path.realpath(path), os.path.realpath(root)
    assert os.path.commonpath([real, real_root]) == real_root and os.path.isfile(real), (name, real)


@pytest.fixture(scope="module")
def tree_once(tmp_path_factory):
    """The tree of :func:`tree` made once for the property test, which runs in its ``work`` folder."""
    base = tmp_path_factory.mktemp("once")
    winter = base / "data" / "winter"
    (winter / "sub").mkdir(parents=True)
    for p in (winter / "a.png", winter / "sub" / "b.png", base / "secret.png", base / "data" / "b.png"):
        p.write_bytes(b"x")
    (winter / "link.png").symlink_to(base / "secret.png")
    (winter / "up").symlink_to(base)
    (base / "work").mkdir()
    old = Path.cwd()
    os.chdir(base / "work")
    yield base
    os.chdir(old)
