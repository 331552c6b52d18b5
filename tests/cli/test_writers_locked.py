"""Every writer takes the lock of its output: while another seqnet process holds it, describe, eval
(``--dataset`` and ``--index``) and localize (``--dataset`` and ``--map``) are refused with one line and
exit 1 naming the holder, and write nothing."""

from __future__ import annotations

import multiprocessing

import numpy as np
import pytest

from seqnet.cli import main
from seqnet.security.locks import locked


def _hold(path, ready, release):
    with locked(path):
        ready.set()
        release.wait(30)


@pytest.fixture
def held():
    """``held(path)``: another (live) process holds the lock of ``path`` until the test ends."""
    ctx = multiprocessing.get_context("fork")
    procs = []

    def hold(path):
        ready, release = ctx.Event(), ctx.Event()
        proc = ctx.Process(target=_hold, args=(path, ready, release))
        proc.start()
        assert ready.wait(20)
        procs.append((proc, release))
        return proc.pid

    yield hold
    for proc, release in procs:
        release.set()
        proc.join(20)


def _refused(argv, capsys, pid):
    capsys.readouterr()
    assert main(argv) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"in use by another seqnet process (PID {pid}" in err[0], err


def test_eval_out_is_locked(synth_dir, tmp_path, capsys, held):
    out = tmp_path / "out"
    _refused(["eval", "--dataset", str(synth_dir), "--method", "single", "--out", str(out)], capsys, held(out))
    assert not (out / "results.json").exists()


def test_eval_index_out_is_locked(synth_dir, tmp_path, capsys, held):
    assert main(["index", "build", "--dataset", str(synth_dir), "--shortlist", "delta", "--rerank", "raw+seqmatch",
                 "--out", str(tmp_path / "map")]) == 0
    out = tmp_path / "out"
    _refused(["eval", "--dataset", str(synth_dir), "--index", str(tmp_path / "map"), "--out", str(out)], capsys,
             held(out))
    assert not (out / "results.json").exists()


def test_localize_outputs_are_locked(synth_dir, synth_dataset, tmp_path, capsys, held):
    out = tmp_path / "t.csv"
    pid = held(out)
    _refused(["localize", "--dataset", str(synth_dir), "--method", "raw+seqmatch", "--out", str(out)], capsys, pid)
    from seqnet.core.provenance import sidecar

    np.save(tmp_path / "q.npy", np.asarray(synth_dataset.query.descriptors[:20]))
    sidecar(tmp_path / "q.npy").write_text(__import__("json").dumps(synth_dataset.query.provenance))
    _refused(["localize", "--map", str(synth_dir), "--query", str(tmp_path / "q.npy"), "--method", "raw+seqmatch",
              "--out", str(out)], capsys, pid)
    assert not out.exists() and not out.with_suffix(".json").exists()


def test_describe_out_is_locked(folder, tmp_path, capsys, held):
    out = tmp_path / "d.npy"
    _refused(["describe", str(folder), "--method", "pixels", "--out", str(out)], capsys, held(out))
    assert not out.exists()


def test_localize_refuses_to_replace_a_users_csv(synth_dir, tmp_path, capsys):
    out = tmp_path / "gps.csv"
    out.write_text("lat,lon\n1,2\n")
    assert main(["localize", "--dataset", str(synth_dir), "--method", "raw+seqmatch", "--out", str(out)]) == 2
    assert "was not written by seqnet localize" in capsys.readouterr().err
    assert out.read_text() == "lat,lon\n1,2\n"
    ours = tmp_path / "ours.csv"
    for _ in range(2):  # a track seqnet wrote is replaced
        assert main(["localize", "--dataset", str(synth_dir), "--method", "raw+seqmatch", "--out", str(ours)]) == 0
    ours.with_suffix(".json").unlink()  # killed between the two files: the track alone is still ours
    assert main(["localize", "--dataset", str(synth_dir), "--method", "raw+seqmatch", "--out", str(ours)]) == 0
