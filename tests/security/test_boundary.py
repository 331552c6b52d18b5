"""The guarded boundary's own pieces: opening inputs, paths from files, arrays against np.load, the sandbox,
CSV cells and terminal text."""

from __future__ import annotations

import os
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import array_shapes, arrays

from seqnet.core.errors import DatasetError
from seqnet.security.arrays import read_npy, read_npz
from seqnet.security.hdf5file import read_hdf5
from seqnet.security.inputs import inside, nofollow_fd, open_input, read_bytes
from seqnet.security.sandbox import run_child
from seqnet.security.text import csv_cell, shown


def test_open_input_refuses_what_is_not_a_regular_file(tmp_path):
    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "d").mkdir()
    with pytest.raises(DatasetError, match="FIFO .*save it to a file first"):
        open_input(tmp_path / "fifo")  # returns at once: opened non-blocking
    with pytest.raises(DatasetError, match="directory"):
        open_input(tmp_path / "d")
    with pytest.raises(DatasetError, match="character device"):
        open_input("/dev/zero")
    with pytest.raises(DatasetError, match="not found"):
        open_input(tmp_path / "none")
    (tmp_path / "f").write_bytes(b"x" * 10)
    (tmp_path / "link").symlink_to(tmp_path / "f")
    assert open_input(tmp_path / "link").read() == b"x" * 10
    with pytest.raises(DatasetError, match="symbolic link"):
        open_input(tmp_path / "link", follow=False)
    with pytest.raises(DatasetError, match="more than the 5"):
        read_bytes(tmp_path / "f", 5)


def test_a_small_file_is_read_without_setting_its_limit_aside(tmp_path):
    """read_bytes read f.read(limit + 1): 1 GiB of address space set aside for a 100-byte names.txt, so under
    ``ulimit -v`` a dataset's load died of MemoryError. Run in a child with 200 MiB of address space to spare."""
    import subprocess
    import sys

    (tmp_path / "names.txt").write_bytes(b"a.png\n" * 20)
    code = ("import re, resource, sys\n"
            "from seqnet.security.inputs import read_bytes\n"
            "vm = int(re.search(r'VmSize:\\s+(\\d+)', open('/proc/self/status').read()).group(1)) * 1024\n"
            "resource.setrlimit(resource.RLIMIT_AS, (vm + (200 << 20), resource.RLIM_INFINITY))\n"
            "assert read_bytes(sys.argv[1], 1 << 30) == b'a.png\\n' * 20\n")
    done = subprocess.run([sys.executable, "-c", code, str(tmp_path / "names.txt")], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr[-500:]


def test_a_file_that_grows_while_read_is_read_on_to_its_limit(tmp_path, monkeypatch):
    (tmp_path / "f").write_bytes(b"x" * 10)
    real = os.fstat
    monkeypatch.setattr(os, "fstat", lambda fd: os.stat_result((*real(fd)[:6], 4, *real(fd)[7:])))  # 4 bytes then
    assert read_bytes(tmp_path / "f", 20) == b"x" * 10
    with pytest.raises(DatasetError, match="grew past 8 bytes"):
        read_bytes(tmp_path / "f", 8)


@pytest.mark.parametrize("rel, ok", [("a/b.npy", True), ("/etc/passwd", False), ("../x", False), ("a/../../x", False),
                                     ("", False), ("a\x00b", False), ("a\\b", False), (5, False), ("link/x", False)])
def test_inside_keeps_paths_from_files_in_their_folder(tmp_path, rel, ok):
    root = tmp_path / "root"
    (root / "a").mkdir(parents=True)
    (root / "link").symlink_to(tmp_path)
    if ok:
        assert inside(root, rel, "test") == root / rel
    else:
        with pytest.raises(DatasetError):
            inside(root, rel, "test")


def test_nofollow_fd_refuses_a_planted_link(tmp_path):
    victim = tmp_path / "victim"
    victim.write_text("precious")
    (tmp_path / "lock").symlink_to(victim)
    with pytest.raises(DatasetError, match="symbolic link"):
        nofollow_fd(tmp_path / "lock", os.O_RDWR | os.O_CREAT)
    assert victim.read_text() == "precious"


DTYPES = st.sampled_from(["<f4", ">f4", "<f8", "<i8", ">i4", "|u1", "|b1", "<f2"])


@settings(max_examples=40, deadline=None)
@given(arrays(DTYPES, array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=5)), st.booleans())
def test_read_npy_equals_np_load(tmp_path_factory, a, fortran):
    """Every plain dtype, byte order, layout and shape (0-d and empty included) reads as np.load reads it."""
    f = tmp_path_factory.mktemp("npy") / "a.npy"
    np.save(f, np.asfortranarray(a) if fortran else a)
    want = np.load(f)
    for mmap in (False, True, "c"):
        got = read_npy(f, mmap)
        assert got.dtype == want.dtype and got.shape == want.shape and np.array_equal(got, want, equal_nan=True)


def test_read_npz_equals_np_load(tmp_path):
    arrays_ = {"a": np.arange(12, dtype=">i4").reshape(3, 4), "b": np.eye(3, dtype=bool), "c": np.zeros(0)}
    for save in (np.savez, np.savez_compressed):
        save(tmp_path / "x.npz", **arrays_)
        got = read_npz(tmp_path / "x.npz")
        with np.load(tmp_path / "x.npz") as z:
            assert set(got) == set(z.files) and all(np.array_equal(got[k], z[k]) for k in z.files)


def test_an_npz_member_flagged_encrypted_is_one_error(tmp_path):
    """Found by an hour of fuzzing: the zip 'encrypted' bit made zipfile raise RuntimeError."""
    np.savez(tmp_path / "x.npz", a=np.arange(3))
    data = bytearray((tmp_path / "x.npz").read_bytes())
    for sig in (b"PK\x03\x04", b"PK\x01\x02"):  # the flag word in the local and the central header
        at = data.find(sig)
        data[at + (6 if sig == b"PK\x03\x04" else 8)] |= 1
    (tmp_path / "x.npz").write_bytes(bytes(data))
    with pytest.raises(DatasetError, match="encrypted"):
        read_npz(tmp_path / "x.npz")


def test_a_truncated_npy_is_refused_before_allocating(tmp_path):
    np.save(tmp_path / "a.npy", np.ones((100, 100)))
    data = (tmp_path / "a.npy").read_bytes()
    (tmp_path / "a.npy").write_bytes(data[:500])
    with pytest.raises(DatasetError, match="holds 372 bytes"):
        read_npy(tmp_path / "a.npy", False)


def test_hdf5_read_in_the_sandbox_equals_h5py(tmp_path):
    rng = np.random.default_rng(0)
    with h5py.File(tmp_path / "a.h5", "w") as h:
        h["descriptors"] = rng.random((50, 7), dtype=np.float32)
        h.create_dataset("big_endian", data=np.arange(10, dtype=">i8"))
        h.create_dataset("chunked", data=rng.random((40, 3)), chunks=(7, 3), compression="gzip")
        h.create_dataset("names", data=np.array(["a", "é", "c"], dtype=object), dtype=h5py.string_dtype())
        h.attrs["provenance"] = "{}"
    got = read_hdf5(tmp_path / "a.h5")
    with h5py.File(tmp_path / "a.h5") as h:
        for k in ("descriptors", "big_endian", "chunked"):
            assert np.array_equal(got.arrays[k], h[k][()]) and got.arrays[k].dtype == h[k].dtype
    assert got.strings["names"] == ["a", "é", "c"] and got.attrs == {"provenance": "{}"}


def test_the_sandbox_is_killed_after_its_time(tmp_path):
    with h5py.File(tmp_path / "a.h5", "w") as h:
        h["descriptors"] = np.ones((4, 4), np.float32)
    with pytest.raises(DatasetError, match="took longer than"):
        with run_child("hdf5", {"path": str(tmp_path / "a.h5"), "limit": 1 << 20}, "test file", 1 << 20, 0.01):
            pass


def test_a_file_that_makes_libhdf5_spin_ends_in_one_error(monkeypatch):
    """Found by ten minutes of fuzzing the HDF5 reader (case 347, seed 11): libhdf5 loops on this 6 KiB file;
    the child is killed at its time bound (30 s + 1 s per 5 MB; 4 s here) and the read is one DatasetError."""
    import time

    import seqnet.security.hdf5file as hdf5

    monkeypatch.setattr(hdf5, "time_bound", lambda size: 4.0)
    start = time.monotonic()
    with pytest.raises(DatasetError, match="took longer than 4 s"):
        read_hdf5(Path(__file__).parent / "files" / "libhdf5_spins.h5")
    assert time.monotonic() - start < 30


def test_csv_cells_and_terminal_text():
    assert [csv_cell(x) for x in ("=1+1", "+a", "-b", "@c", "\tx", "\ry", "ok", 5, -3.5)] == \
        ["'=1+1", "'+a", "'-b", "'@c", "'\tx", "'\ry", "ok", 5, -3.5]
    assert shown("a\x1b[2Jb\x00c\u2028") == "a\\x1b[2Jb\\x00c\\u2028" and shown("naïve ok") == "naïve ok"
