"""A pipeline command's outputs (seqnet.pipelines.outputs): one version swapped in whole, whatever the kill point;
errors name the user's path, never the temporary folder; the working folders of killed runs are removed by the
next run; a user's files are kept."""

from __future__ import annotations

import errno
import fcntl
import json
import os
import tempfile

import pytest
from conftest import each_crash_point, restorer

from seqnet.cli import main as cli_main
from seqnet.core.errors import OutputError
from seqnet.data.io import load_dataset
from seqnet.pipelines import outputs
from seqnet.pipelines.demo import DemoConfig
from seqnet.pipelines.demo import main as demo


def marked(root):
    """The temporary folders and files seqnet made beside ``root`` that are still there."""
    return sorted(p.name for p in root.parent.iterdir() if p.name.startswith(f".{root.name}.seqnet-"))


def test_a_killed_demo_leaves_one_whole_version(tmp_path):
    """The results of one run never sit beside the dataset of another (places 100 and 150), at any kill point;
    the next run removes what the killed one left."""
    out, saved = tmp_path / "demo", tmp_path / "saved"
    saved.mkdir()
    (saved / "notes.txt").write_text("mine")
    old, new = (DemoConfig(places=n, train_models=False, device="cpu") for n in (100, 150))
    demo(old, saved)

    restore = restorer(saved, out)

    def check():
        places = json.loads((out / "results.json").read_text())["config"]["demo"]["places"]
        assert len(load_dataset(out / "dataset").reference) in {100: range(90, 100), 150: range(140, 150)}[places]
        assert (out / "notes.txt").read_text() == "mine"

    # the state after rename k is the state before rename k + 1 (the renames inside the new version's
    # temporary folder are unseen)
    assert each_crash_point(restore, demo, new, out, check=check, modes=("after",)) > 6
    demo(new, out)
    assert marked(out) == [] and (out / "notes.txt").read_text() == "mine"


@pytest.mark.parametrize("failure", ["disk full", "refused"])
def test_an_error_inside_the_temporary_folder_names_the_users_path(tmp_path, capsys, monkeypatch, failure):
    import seqnet.pipelines.demo as demo_module

    def failing(path, obj):
        if failure == "disk full":
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        raise OutputError(f"{path}: refused for a test")

    monkeypatch.setattr(demo_module, "write_json_atomic", failing)
    out = tmp_path / "out"
    rc = cli_main(["-q", "demo", "--places", "200", "--no-train", "--out", str(out), "--device", "cpu"])
    err = capsys.readouterr().err.strip()
    assert rc == (1 if failure == "disk full" else 2) and len(err.splitlines()) == 1
    assert f"{out / 'results.json'}:" in err and ".seqnet-" not in err, err
    assert not out.exists() and marked(out) == []


def test_a_demo_without_out_leaves_nothing_and_removes_what_killed_ones_left(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    dead, live = tmp_path / "seqnet-demo-run-123-dead", tmp_path / "seqnet-demo-run-456-live"
    old = tmp_path / "seqnet-demo-abcd1234"  # an older seqnet's (no lock: maybe running): never touched
    for d in (dead, live, old):
        (d / "demo" / "dataset").mkdir(parents=True)
    (tmp_path / f".{dead.name}.lock").write_text("PID 123 on host since then: seqnet demo")  # its holder died
    (tmp_path / ".seqnet-demo-run-789-gone.lock").write_text("PID 789 on host since then: seqnet demo")  # no folder
    holder = os.open(tmp_path / f".{live.name}.lock", os.O_RDWR | os.O_CREAT)
    fcntl.flock(holder, fcntl.LOCK_EX)  # a demo still running
    mine = tmp_path / "seqnet-demo-run-notes.txt"  # a file, not a demo's folder
    mine.write_text("mine")
    try:
        assert cli_main(["demo", "--places", "200", "--no-train", "--device", "cpu"]) == 0
    finally:
        os.close(holder)
    assert "done in" in capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([f".{live.name}.lock", live.name, old.name, mine.name])


def test_outputs_are_checked_before_any_work_and_other_files_kept(tmp_path):
    root = tmp_path / "r"
    root.mkdir()
    (root / "mine.txt").write_text("mine")

    def write(tmp):
        (tmp / "a.json").write_text("{}")
        (tmp / "sub").mkdir()
        (tmp / "sub" / "b.txt").write_text("b")

    outputs.write_outputs(root, "test one", "test outputs", write)
    record = json.loads((root / outputs.RECORD).read_text())["entries"]
    assert set(record) == {"a.json", "sub"} and record["sub"]["kind"] == "test one"
    assert outputs.written_by(root, "sub") == "test one"
    outputs.check_outputs_of(root, ["a.json", "sub", "mine.txt2"], "test one", "test outputs")  # its own: fine
    with pytest.raises(OutputError, match=r"a.json was written by `seqnet test one`, not by `seqnet test two`"):
        outputs.check_outputs_of(root, ["a.json"], "test two", "test outputs")
    outputs.check_outputs_of(root, ["a.json"], "test two", "test outputs", overwrite=True)
    with pytest.raises(OutputError, match=r"mine.txt was not written by seqnet"):
        outputs.check_outputs_of(root, ["mine.txt"], "test one", "test outputs", overwrite=True)
    (root / "sub" / "b.txt").write_text("changed by hand")  # no longer what the command wrote
    with pytest.raises(OutputError, match=r"sub was written by another seqnet command \(or changed since\)"):
        outputs.check_outputs_of(root, ["sub"], "test one", "test outputs")
    assert (root / "mine.txt").read_text() == "mine"


def test_hostile_names_are_shown_escaped(tmp_path):
    root = tmp_path / "r"
    root.mkdir()
    evil = "\x1b]0;owned\x07.json"
    (root / evil).write_text("mine")
    with pytest.raises(OutputError) as e:
        outputs.check_outputs_of(root, [evil], "test one", "test outputs")
    assert "\x1b" not in str(e.value) and "\\x1b]0;owned\\x07.json" in str(e.value)
