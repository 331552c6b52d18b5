"""A run killed (SIGKILL) at any point, or stopped by a file size limit, is resumable or restartable, and the
next command says which; a directory holding anything seqnet did not write is refused, never emptied.

The kills are real: one worker process imports seqnet and torch once and forks a child per kill point; the
child arms the point (just before / after the n-th atomic rename onto a run file, or at the start of an
epoch) and SIGKILLs itself there, leaving what a killed run leaves (temporary files, a half-started events
file, the lock file beside the run). Every run finishes with the weights of an uninterrupted run.
"""

from __future__ import annotations

import json
import resource
import shutil
import signal
import subprocess
import sys

import pytest
import torch

from seqnet.cli import main as cli_main
from seqnet.data.io import save_dataset
from seqnet.data.synth import make_synthetic
from seqnet.sequence.checkpoints import read_checkpoint

ARGS = ["--epochs", "2", "--seq-len", "3", "--w", "2", "--out-dims", "8", "--optimizer", "adam", "--lr", "1e-2",
        "--n-neg-sample", "50", "--cache-refresh", "40", "--device", "cpu", "--val-split", "none"]

WORKER = r"""
import json, os, signal, sys
import torch  # imported before forking (no torch op runs in this process), as is what training imports
import torch.utils.tensorboard
import seqnet.cli
import seqnet.data.io
import seqnet.train.loop as loop

torch.optim.Adam([torch.zeros(1, requires_grad=True)])  # the optimiser's first use imports torch._dynamo: once


def kill():
    os.kill(os.getpid(), signal.SIGKILL)


def arm(point):
    kind, _, rest = point.partition(":")
    name, _, nth = rest.partition("#")
    nth, seen = int(nth or 1), [0]
    if kind == "epoch":
        real_epoch = loop.train_epoch

        def train_epoch(run, src, epoch):
            if epoch == int(name):
                seen[0] += 1
                if seen[0] == nth:
                    kill()
            return real_epoch(run, src, epoch)

        loop.train_epoch = train_epoch
        return
    real_replace = os.replace

    def replace(src, dst, *a, **k):
        mine = os.path.basename(str(dst)) == name
        seen[0] += mine
        if mine and seen[0] == nth and kind == "before":
            kill()
        real_replace(src, dst, *a, **k)
        if mine and seen[0] == nth and kind == "after":
            kill()

    os.replace = replace


status = []
for point, argv in json.loads(sys.argv[1]):
    pid = os.fork()
    if pid == 0:
        torch.set_num_threads(1)
        arm(point)
        os._exit(100 + seqnet.cli.main(["-q", "--threads", "1", *argv]))
    status.append(os.waitpid(pid, 0)[1])
print(json.dumps(status))
"""


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return save_dataset(make_synthetic(places=200, dim=8), tmp_path_factory.mktemp("kills") / "ds")


@pytest.fixture(scope="module")
def straight(data, tmp_path_factory):
    out = tmp_path_factory.mktemp("straight") / "run"
    assert cli_main(["-q", "--threads", "1", "train", "--dataset", str(data), "--out", str(out), *ARGS]) == 0
    return read_checkpoint(out / "last.pt")


def _kill_at(tmp_path, jobs):
    """Run each ``(point, argv)`` in a child killed at ``point``; every child must die of SIGKILL there."""
    (tmp_path / "worker.py").write_text(WORKER)
    p = subprocess.run([sys.executable, str(tmp_path / "worker.py"), json.dumps(jobs)], capture_output=True,
                       text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    status = json.loads(p.stdout.strip().splitlines()[-1])
    for (point, _), st in zip(jobs, status, strict=True):
        assert st & 0x7F == signal.SIGKILL, (point, st, p.stderr[-2000:])


def _same_weights(run_dir, straight):
    last = read_checkpoint(run_dir / "last.pt")
    assert last["epoch"] == 2
    for key, value in straight["state_dict"].items():
        assert torch.equal(value, last["state_dict"][key]), key


def _cli(capsys, argv):
    capsys.readouterr()
    rc = cli_main(["--threads", "1", *argv])
    return rc, capsys.readouterr().err.strip().splitlines()


NO_CONFIG, RESTART, RESUME = "no config", "restart", "resume"
POINTS = [
    ("before:.seqnet-manifest.json#1", NO_CONFIG),  # only the manifest's temporary file
    ("after:.seqnet-manifest.json#1", NO_CONFIG),  # the manifest alone
    ("before:config.json#1", NO_CONFIG),  # config.json's temporary file
    ("before:.seqnet-manifest.json#2", RESTART),  # the events file opened, not yet in the manifest
    ("epoch:1", RESTART),
    ("before:best.pt#1", RESTART),
    ("after:best.pt#1", RESTART),  # best.pt of epoch 1 without last.pt (was stuck: D7b)
    ("before:last.pt#1", RESTART),
    ("after:last.pt#1", RESUME),
    ("after:best.pt#2", RESUME),  # best.pt of epoch 2, last.pt of epoch 1: resuming redoes epoch 2
]


def test_every_kill_point_is_resumable_or_restartable_and_says_which(data, straight, tmp_path, capsys):
    killed = tmp_path / "killed"
    jobs = [(point, ["train", "--dataset", str(data), "--out", str(killed / f"r{i}"), *ARGS])
            for i, (point, _) in enumerate(POINTS)]
    _kill_at(tmp_path, jobs)
    for i, (point, state) in enumerate(POINTS):
        src, again, resumed = killed / f"r{i}", tmp_path / f"again{i}", tmp_path / f"resumed{i}"
        assert not (src / "last.pt").exists() if state != RESUME else (src / "last.pt").is_file(), point
        shutil.copytree(src, again)
        shutil.copytree(src, resumed)
        # the same command again
        rc, err = _cli(capsys, ["train", "--dataset", str(data), "--out", str(again), *ARGS])
        if state == RESUME:
            assert rc == 2 and len(err) == 1 and f"--resume {again}" in err[0], (point, err)
        else:
            assert rc == 0, (point, err)
            assert any("starting a new run in its place" in line for line in err), (point, err)
            _same_weights(again, straight)
        # --resume
        rc, err = _cli(capsys, ["train", "--resume", str(resumed)])
        if state == NO_CONFIG:
            assert rc == 2 and len(err) == 1 and "stopped before it saved its configuration" in err[0], (point, err)
            assert "run the same training command again" in err[0]
            continue
        assert rc == 0, (point, err)
        said = "resuming" if state == RESUME else "starting it again from epoch 1 with its stored configuration"
        assert any(said in line for line in err), (point, err)
        _same_weights(resumed, straight)
        assert not [p.name for p in resumed.iterdir() if p.name.endswith(".tmp")], point


def test_a_killed_joint_run_resumes_with_its_recorded_dataset(data, tmp_path, capsys):
    joint = [*ARGS[:-2], "--joint"]  # validation on (S_1 with val none would equal it too; keep the default)
    jobs = [("epoch:1#1", ["train", "--dataset", str(data), "--out", str(tmp_path / "j0"), *joint]),
            ("epoch:1#2", ["train", "--dataset", str(data), "--out", str(tmp_path / "j1"), *joint])]
    _kill_at(tmp_path, jobs)
    stored = json.loads((tmp_path / "j0" / "joint.json").read_text())
    assert stored["dataset_path"] == str(data.resolve())
    # killed in S_L's first epoch: --resume finds the dataset (it was "no dataset: give --dataset DIR")
    shutil.copytree(tmp_path / "j0", tmp_path / "j0b")
    rc, err = _cli(capsys, ["train", "--resume", str(tmp_path / "j0")])
    assert rc == 0, err
    assert any("starting a new run in its place" in line for line in err), err
    assert read_checkpoint(tmp_path / "j0" / "s1" / "last.pt")["epoch"] == 2
    # the same command again starts it again too
    rc, err = _cli(capsys, ["train", "--dataset", str(data), "--out", str(tmp_path / "j0b"), *joint])
    assert rc == 0 and any("joint run that stopped before either model saved an epoch" in x for x in err), err
    # killed in S_1's first epoch (S_L done): a new run is refused with the hint, --resume finishes S_1
    rc, err = _cli(capsys, ["train", "--dataset", str(data), "--out", str(tmp_path / "j1"), *joint])
    assert rc == 2 and len(err) == 1 and f"--resume {tmp_path / 'j1'}" in err[0], err
    rc, err = _cli(capsys, ["train", "--resume", str(tmp_path / "j1"), "--lr", "0.5"])
    assert rc == 2 and len(err) == 1 and "cannot change 'lr' when resuming the joint run" in err[0], err
    rc, err = _cli(capsys, ["train", "--resume", str(tmp_path / "j1")])
    assert rc == 0, err
    assert read_checkpoint(tmp_path / "j1" / "s1" / "last.pt")["epoch"] == 2


def _fsize_limit(n):
    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (n, n))

    return limit


def test_a_file_size_limit_between_best_and_last_is_exit_1_and_the_run_starts_again(data, straight, tmp_path,
                                                                                      capsys):
    """``ulimit -f`` that lets best.pt (~3 KB) through and cuts last.pt (~20 KB) short: one line, exit 1, naming
    RUN/last.pt (not torch's inline_container message); RUN keeps best.pt without last.pt, which the same
    command or --resume starts again (it was stuck: "not empty" / "checkpoint not found")."""
    run = tmp_path / "r"
    p = subprocess.run([sys.executable, "-m", "seqnet", "-q", "--threads", "1", "train", "--dataset", str(data),
                        "--out", str(run), *ARGS], preexec_fn=_fsize_limit(10_000), capture_output=True, text=True,
                       timeout=300)
    err = p.stderr.strip().splitlines()
    assert p.returncode == 1 and len(err) == 1 and "Traceback" not in p.stderr, p.stderr[-2000:]
    assert f"disk full (or a file size limit, ulimit -f) writing {run / 'last.pt'} in epoch 1" in err[0]
    assert "inline_container" not in err[0] and "enforce fail" not in err[0] and "check the free space" in err[0]
    assert (run / "best.pt").is_file() and not (run / "last.pt").exists()
    assert not [x.name for x in run.iterdir() if x.name.endswith(".tmp")]
    assert not list(tmp_path.glob(".*.lock"))
    shutil.copytree(run, tmp_path / "copy")
    rc, err = _cli(capsys, ["train", "--resume", str(run)])
    assert rc == 0 and any("discarding best.pt" in line for line in err), err
    _same_weights(run, straight)
    rc, err = _cli(capsys, ["train", "--dataset", str(data), "--out", str(tmp_path / "copy"), *ARGS])
    assert rc == 0 and any("discarding best.pt" in line for line in err), err
    _same_weights(tmp_path / "copy", straight)


def test_a_full_disk_after_the_first_epoch_says_resume(data, tmp_path, capsys, monkeypatch):
    import seqnet.train.run as run_module
    from seqnet.core.errors import ResourceError

    real = run_module.save_checkpoint

    def save(path, model, **fields):
        if fields["epoch"] == 2:
            raise ResourceError("disk full ([enforce fail at inline_container.cc:672] . unexpected pos 1 vs 2)")
        return real(path, model, **fields)

    monkeypatch.setattr(run_module, "save_checkpoint", save)
    rc, err = _cli(capsys, ["-q", "train", "--dataset", str(data), "--out", str(tmp_path / "r"), *ARGS])
    assert rc == 1 and len(err) == 1 and "inline_container" not in err[0], err
    assert f"writing {tmp_path / 'r' / 'best.pt'} in epoch 2; {tmp_path / 'r'} still holds the run as of epoch 1" \
        in err[0] and f"then seqnet train --resume {tmp_path / 'r'}" in err[0], err


def test_a_full_disk_writing_the_events_is_one_line_and_the_run_resumes(data, tmp_path, capsys, monkeypatch):
    """TensorBoard writes its events in place (not atomically): a full disk there is one line naming the run's
    state (last.pt of that epoch is written first), and closing the writer cannot hide it."""
    import errno

    from torch.utils.tensorboard import SummaryWriter

    real_add, real_close = SummaryWriter.add_scalar, SummaryWriter.close

    def add_scalar(self, key, value, step):
        if step == 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_add(self, key, value, step)

    def close(self):
        real_close(self)
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(SummaryWriter, "add_scalar", add_scalar)
    monkeypatch.setattr(SummaryWriter, "close", close)
    run = tmp_path / "r"
    args = [*ARGS[:ARGS.index("--epochs")], "--epochs", "3", *ARGS[ARGS.index("--epochs") + 2:]]  # given once
    rc, err = _cli(capsys, ["-q", "train", "--dataset", str(data), "--out", str(run), *args])
    assert rc == 1 and len(err) == 1, err
    assert f"writing the TensorBoard events in {run} in epoch 2; {run} holds the run as of epoch 2" in err[0], err
    monkeypatch.undo()
    rc, err = _cli(capsys, ["train", "--resume", str(run)])
    assert rc == 0 and any("resuming" in x for x in err) and read_checkpoint(run / "last.pt")["epoch"] == 3, err
