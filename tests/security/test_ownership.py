"""Locks and manifests: a second writer is refused, a user's files are never replaced or deleted."""

from __future__ import annotations

import errno
import multiprocessing
import os

import numpy as np
import pytest

from seqnet.core.errors import LockedError, OutputError, ResourceError
from seqnet.data.io import load_dataset, save_dataset
from seqnet.security.files import atomic_path, os_error, write_json_atomic, write_text_atomic
from seqnet.security.locks import lock_file, locked
from seqnet.security.ownership import MANIFEST, check_replaceable, foreign_files, remove_owned_dir


def _hold(path, ready, release):
    with locked(path):
        ready.set()
        release.wait(20)


@pytest.fixture
def other_process_lock(tmp_path):
    """A lock on tmp_path/run held by another (live) process."""
    ctx = multiprocessing.get_context("fork")
    ready, release = ctx.Event(), ctx.Event()
    proc = ctx.Process(target=_hold, args=(tmp_path / "run", ready, release))
    proc.start()
    assert ready.wait(20)
    yield tmp_path / "run", proc
    release.set()
    proc.join(20)


def test_second_writer_is_refused_naming_the_holder(other_process_lock):
    path, proc = other_process_lock
    with pytest.raises(LockedError, match=f"in use by another seqnet process \\(PID {proc.pid}"):
        with locked(path):
            pass
    assert LockedError("x").exit_code == 1


def test_lock_of_a_killed_process_is_taken_over(tmp_path):
    ctx = multiprocessing.get_context("fork")
    ready, release = ctx.Event(), ctx.Event()
    proc = ctx.Process(target=_hold, args=(tmp_path / "run", ready, release))
    proc.start()
    assert ready.wait(20)
    proc.kill()
    proc.join(20)
    assert lock_file(tmp_path / "run").exists()  # the file stays, the kernel released the lock
    with locked(tmp_path / "run"):
        assert f"PID {os.getpid()}" in lock_file(tmp_path / "run").read_text()
    assert not lock_file(tmp_path / "run").exists()


def test_lock_is_reentrant_in_one_process(tmp_path):
    with locked(tmp_path / "d"), locked(tmp_path / "d"):
        pass
    assert not lock_file(tmp_path / "d").exists()


def test_concurrent_save_dataset_is_refused(tmp_path, synth_dataset, other_process_lock):
    path, _ = other_process_lock
    with pytest.raises(LockedError):
        save_dataset(synth_dataset, path)
    assert not path.exists()


def test_overwrite_refuses_a_directory_with_user_files(tmp_path, synth_dataset):
    root = save_dataset(synth_dataset, tmp_path / "ds")
    assert (root / MANIFEST).is_file() and foreign_files(root) == []
    (root / "my_notes.txt").write_text("precious")
    with pytest.raises(OutputError, match="1 file\\(s\\) seqnet did not write \\(first: my_notes.txt\\)"):
        save_dataset(synth_dataset, root, overwrite=True)
    assert (root / "my_notes.txt").read_text() == "precious" and load_dataset(root).name == "synthetic"


def test_overwrite_refuses_a_non_dataset_directory(tmp_path, synth_dataset):
    home = tmp_path / "home"
    (home / "photos").mkdir(parents=True)
    (home / "photos" / "a.jpg").write_bytes(b"jpg")
    with pytest.raises(OutputError, match="seqnet did not write"):
        save_dataset(synth_dataset, home, overwrite=True)
    assert (home / "photos" / "a.jpg").read_bytes() == b"jpg"


def test_legacy_dataset_without_manifest_can_be_replaced(tmp_path, synth_dataset):
    root = save_dataset(synth_dataset, tmp_path / "ds")
    (root / MANIFEST).unlink()
    save_dataset(synth_dataset, root, overwrite=True)  # only files seqnet writes: replaceable
    assert (root / MANIFEST).is_file()


def test_remove_owned_dir(tmp_path):
    d = tmp_path / "run"
    d.mkdir()
    (d / "a.pt").write_text("x")
    with pytest.raises(OutputError):
        remove_owned_dir(d, "run")
    from seqnet.security.ownership import write_manifest

    write_manifest(d, "run", [d / "a.pt"])
    remove_owned_dir(d, "run")
    assert not d.exists()
    remove_owned_dir(d, "run")  # nothing to do
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(OutputError, match="not a directory"):
        check_replaceable(f, "run")


@pytest.mark.parametrize("err, cls, text", [
    (errno.ENOSPC, ResourceError, "no space left on device"),
    (errno.EROFS, ResourceError, "read-only file system"),
    (errno.EACCES, ResourceError, "permission denied"),
    (errno.ENOTDIR, OutputError, "is a file, not a directory"),
    (errno.EEXIST, OutputError, "a file is in the way"),
])
def test_atomic_writer_names_the_users_path_on_os_failure(tmp_path, monkeypatch, err, cls, text):
    target = tmp_path / "out.json"

    def fail(*a, **k):
        raise OSError(err, os.strerror(err), a[0] if a else None)

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(OSError) as e:
        write_text_atomic(target, "hello")
    assert e.value.filename == str(target) and e.value.errno == err
    mapped = os_error(e.value)
    assert isinstance(mapped, cls) and text in str(mapped) and str(target) in str(mapped)
    assert list(tmp_path.iterdir()) == []  # no temporary file left


def test_atomic_writer_onto_directory_names_it(tmp_path):
    (tmp_path / "d").mkdir()
    with pytest.raises(IsADirectoryError) as e:
        with atomic_path(tmp_path / "d"):
            pass
    assert e.value.filename == str(tmp_path / "d")


def test_json_refuses_nan(tmp_path):
    from seqnet.core.errors import ConfigError

    with pytest.raises(ConfigError, match="NaN or inf"):
        write_json_atomic(tmp_path / "r.json", {"recall@1": float("nan")})
    assert not (tmp_path / "r.json").exists()
    write_json_atomic(tmp_path / "r.json", {"a": np.float32(0.5), "b": np.arange(2)})
