"""Crash consistency: a writer killed (``os._exit``, as ``kill -9``) before or after any rename it makes
leaves its output either wholly the old version or wholly the new one — never missing, never mixed —
and the next writer repairs what the dead one left (no ``.old`` / ``.tmp`` stays behind)."""

from __future__ import annotations

import multiprocessing
import os

import pytest

import seqnet.core.ownership as ownership
from seqnet.data.io import load_dataset, save_dataset
from seqnet.data.synth import make_synthetic


def _crash_at(k: int, when: str, target, *args) -> None:
    """In a forked child: run ``target(*args)``, dying at the ``k``-th rename (``before`` or ``after`` it)."""
    count = [0]

    def wrap(fn):
        def inner(*a, **kw):
            count[0] += 1
            if count[0] == k and when == "before":
                os._exit(9)
            out = fn(*a, **kw)
            if count[0] == k and when == "after":
                os._exit(9)
            return out
        return inner

    os.rename, os.replace = wrap(os.rename), wrap(os.replace)
    ownership.exchange = wrap(ownership.exchange)
    target(*args)
    os._exit(0)


def _run(k, when, target, *args) -> int:
    proc = multiprocessing.get_context("fork").Process(target=_crash_at, args=(k, when, target, *args))
    proc.start()
    proc.join(60)
    return proc.exitcode


def _leftovers(root):
    return sorted(p.name for p in root.parent.iterdir() if p.name.startswith(f".{root.name}.") and
                  not p.name.endswith(".lock"))


@pytest.mark.parametrize("when", ["before", "after"])
def test_dataset_replacement_is_never_missing_or_mixed(tmp_path, when):
    old, new = make_synthetic(places=100, dim=8, seed=1), make_synthetic(places=100, dim=8, seed=2)
    old.name, new.name = "old", "new"
    root = tmp_path / "ds"
    for k in range(1, 40):
        save_dataset(old, root, overwrite=True)
        code = _run(k, when, save_dataset, new, root, True)
        got = load_dataset(root)  # always there, always one whole version
        assert got.name in ("old", "new"), k
        want = new if got.name == "new" else old
        assert (got.reference.descriptors == want.reference.descriptors).all(), k
        save_dataset(old, root, overwrite=True)  # the next writer repairs what the dead one left
        assert _leftovers(root) == [] and load_dataset(root).name == "old"
        if code == 0:  # the writer made fewer than k renames: every crash point was tried
            break
    else:
        pytest.fail("more renames than expected")
    assert k > 3


def test_an_interrupted_two_step_replacement_is_repaired(tmp_path, monkeypatch):
    """Where the file system cannot exchange directories, the old one is moved aside first; killed
    there, the next writer (or reader after it) finds it restored."""
    monkeypatch.setattr(ownership, "exchange", lambda a, b: False)
    old, new = make_synthetic(places=100, dim=8, seed=1), make_synthetic(places=100, dim=8, seed=2)
    old.name, new.name = "old", "new"
    root = tmp_path / "ds"
    save_dataset(old, root)
    for k in range(1, 40):
        code = _run(k, "after", save_dataset, new, root, True)
        save_dataset(old, root, overwrite=True)
        assert load_dataset(root).name == "old" and _leftovers(root) == []
        if code == 0:
            break


def test_a_reader_during_a_replacement_sees_one_version(tmp_path, monkeypatch):
    """The dataset is replaced between the reader's reading of its two traverses: the reader starts again
    and returns the new version whole (never the old reference with the new query)."""
    import seqnet.data.io as io

    old, new = make_synthetic(places=100, dim=8, seed=1), make_synthetic(places=100, dim=8, seed=2)
    old.name, new.name = "old", "new"
    root = tmp_path / "ds"
    save_dataset(old, root)
    real, calls = io.load_traverse, []

    def replacing(*a, **kw):
        t = real(*a, **kw)
        calls.append(1)
        if len(calls) == 1:
            save_dataset(new, root, overwrite=True)  # a writer swaps the directory in mid-read
        return t

    monkeypatch.setattr(io, "load_traverse", replacing)
    got = load_dataset(root)
    assert got.name == "new" and len(calls) > 2
    assert (got.reference.descriptors == new.reference.descriptors).all()
    assert (got.query.descriptors == new.query.descriptors).all()
