"""The environment error boundary: a failing environment is one line on stderr and exit 1, never a
traceback or a signal: a reader that went away (broken pipe), a file size limit (``ulimit -f``), an
address-space limit hit inside torch's allocator (``ulimit -v``)."""

from __future__ import annotations

import os
import resource
import subprocess
import sys

import pytest

from seqnet.cli import main
from seqnet.cli.runtime import is_allocation_error

SEQNET = [sys.executable, "-m", "seqnet"]


def _one_line_exit_1(p: subprocess.CompletedProcess, needle: str) -> None:
    err = p.stderr.strip().splitlines()
    assert p.returncode == 1, (p.returncode, p.stderr[-2000:])
    assert len(err) == 1 and needle in err[0] and "Traceback" not in p.stderr, p.stderr[-2000:]


def test_a_reader_that_went_away_is_exit_1(synth_dir):
    r, w = os.pipe()
    os.close(r)  # the reader is gone before seqnet prints its table
    try:
        p = subprocess.run([*SEQNET, "eval", "--dataset", str(synth_dir), "--method", "single"], stdout=w,
                           stderr=subprocess.PIPE, text=True, timeout=300)
    finally:
        os.close(w)
    _one_line_exit_1(p, "broken pipe")


def test_a_file_size_limit_is_exit_1_not_a_signal(synth_dir, tmp_path):
    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (20000, 20000))

    p = subprocess.run([*SEQNET, "eval", "--dataset", str(synth_dir), "--method", "single,raw+seqmatch",
                        "--out", str(tmp_path / "out")], preexec_fn=limit, capture_output=True, text=True,
                       timeout=300)
    _one_line_exit_1(p, "file too large")


@pytest.mark.skipif(sys.platform != "linux", reason="RLIMIT_AS behaves like this on Linux")
def test_an_allocation_beyond_the_address_space_limit_is_exit_1(tmp_path):
    """An S_5 (w = 5) from D = 1,000 to 250,000 needs a 5 GB weight; under a 3.5 GB address-space limit the
    memory estimate refuses it before anything is allocated (``ulimit -v`` counts): one line, exit 1, and
    no run directory is left behind. (Should an allocator fail anyway, it is one line too: the next test.)"""
    assert main(["-q", "synth", str(tmp_path / "wide"), "--places", "300", "--dim", "1000"]) == 0

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (3_500_000_000, 3_500_000_000))

    out = tmp_path / "run"
    p = subprocess.run([*SEQNET, "train", "--dataset", str(tmp_path / "wide"), "--seq-len", "5", "--w", "5",
                        "--out-dims", "250000", "--epochs", "1", "--out", str(out)], preexec_fn=limit,
                       capture_output=True, text=True, timeout=300)
    _one_line_exit_1(p, "needs about")
    assert "GiB available; hint: --out-dims 512 (saves about" in p.stderr and not out.exists()


def test_allocator_errors_are_told_from_other_runtime_errors():
    assert is_allocation_error(RuntimeError("[enforce fail at alloc_cpu.cpp:127] DefaultCPUAllocator: can't "
                                            "allocate memory: you tried to allocate 7372800000 bytes"))
    assert is_allocation_error(RuntimeError("CUDA out of memory. Tried to allocate 2.00 GiB"))
    assert not is_allocation_error(RuntimeError("shape mismatch"))


def test_describe_under_a_file_size_limit_is_refused_before_hdf5_can_fail(tmp_path):
    """HDF5 does not fail cleanly past a file size limit (tracebacks, then a segfault): describe refuses
    up front, one line, exit 1, and leaves nothing behind."""
    import numpy as np
    from PIL import Image

    images = tmp_path / "imgs"
    images.mkdir()
    rng = np.random.default_rng(0)
    for i in range(10):
        Image.fromarray(rng.integers(0, 256, (32, 64, 3), dtype=np.uint8)).save(images / f"{i}.png")

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (16384, 16384))

    out = tmp_path / "out"
    out.mkdir()
    p = subprocess.run([*SEQNET, "-q", "describe", str(images), "--method", "pixels", "--out", str(out / "d.npy")],
                       preexec_fn=limit, capture_output=True, text=True, timeout=300)
    _one_line_exit_1(p, "file size limit")
    assert list(out.iterdir()) == []
