"""``update_folder(..., drop=names)``: an earlier set's output that this run does not write leaves with that set
when seqnet wrote it; a user's file of that name is carried over untouched."""

from __future__ import annotations

import json

from seqnet.security.folders import update_folder


def _writer(*names):
    def write(tmp):
        for n in names:
            (tmp / n).write_text(f"new {n}")
        return [tmp / n for n in names]
    return write


def test_drop_removes_only_seqnets_own_stale_outputs(tmp_path):
    root = tmp_path / "out"
    update_folder(root, _writer("a.json", "b.html"), "results")
    (root / "mine.txt").write_text("mine")
    update_folder(root, _writer("a.json"), "results", drop=("a.json", "b.html"))
    assert sorted(p.name for p in root.iterdir()) == [".seqnet-manifest.json", "a.json", "mine.txt"]
    assert json.loads((root / ".seqnet-manifest.json").read_text())["files"] == ["a.json"]
    (root / "b.html").write_text("the user's own b.html")  # not in the manifest: never dropped
    update_folder(root, _writer("a.json"), "results", drop=("a.json", "b.html"))
    assert (root / "b.html").read_text() == "the user's own b.html" and (root / "mine.txt").read_text() == "mine"
    update_folder(root, _writer("a.json"), "results")  # without drop: an earlier output of seqnet's is kept
    assert (root / "b.html").exists()
