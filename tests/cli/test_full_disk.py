"""A full disk (a 3 MiB tmpfs) is one line and exit 1 for the writers, never a traceback, a segfault or a
SIGBUS, and leaves neither temporary files nor lock files behind. Needs root to mount a tmpfs."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

SEQNET = [sys.executable, "-m", "seqnet"]


@pytest.fixture
def tiny_disk(tmp_path):
    mnt = tmp_path / "disk"
    mnt.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=3m", "tmpfs", str(mnt)], capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({r.stderr.strip() or 'not root'}); the full-disk cases need one")
    yield mnt
    subprocess.run(["umount", str(mnt)], check=False)


def _one_line_exit_1(p, needle):
    assert p.returncode == 1, (p.returncode, p.stderr[-1500:])
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0] and "Traceback" not in p.stderr, p.stderr[-1500:]


def _clean(mnt):
    left = sorted(p.name for p in mnt.iterdir())
    assert not [n for n in left if n.endswith((".tmp", ".lock", ".old", ".h5"))], left


def test_describe_is_refused_before_it_fills_the_disk(tiny_disk, tmp_path):
    images = tmp_path / "imgs"
    images.mkdir()
    rng = np.random.default_rng(0)
    for i in range(200):  # 200 × 64×32 greyscale pixels: 3.3 MB of descriptors, twice
        Image.fromarray(rng.integers(0, 256, (32, 64, 3), dtype=np.uint8)).save(images / f"{i:03d}.png")
    p = subprocess.run([*SEQNET, "-q", "describe", str(images), "--method", "pixels",
                        "--out", str(tiny_disk / "d.npy")], capture_output=True, text=True, timeout=300)
    _one_line_exit_1(p, "MiB free")
    _clean(tiny_disk)


def test_index_build_on_a_full_disk(tiny_disk, tmp_path):
    from seqnet.cli import main

    assert main(["-q", "synth", str(tmp_path / "ds"), "--places", "2000", "--dim", "256"]) == 0
    p = subprocess.run([*SEQNET, "-q", "index", "build", "--dataset", str(tmp_path / "ds"), "--shortlist", "delta",
                        "--rerank", "raw+seqmatch", "--split", "all", "--out", str(tiny_disk / "map")],
                       capture_output=True, text=True, timeout=300)
    _one_line_exit_1(p, "no space left on device")
    assert str(tiny_disk / "map") in p.stderr and ".tmp" not in p.stderr  # the user's path, not a temporary one
    _clean(tiny_disk)


def test_train_on_a_full_disk(tiny_disk, tmp_path):
    from seqnet.cli import main

    assert main(["-q", "synth", str(tmp_path / "ds"), "--places", "300", "--dim", "1024"]) == 0
    p = subprocess.run([*SEQNET, "-q", "train", "--dataset", str(tmp_path / "ds"), "--seq-len", "5", "--w", "3",
                        "--epochs", "1", "--out", str(tiny_disk / "run")], capture_output=True, text=True, timeout=300)
    assert p.returncode == 1 and "Traceback" not in p.stderr, p.stderr[-1500:]
    said = [line for line in p.stderr.strip().splitlines() if not line.startswith(("the val split", "advice: "))]
    assert len(said) == 1 and "hint: check the free space" in p.stderr
    _clean(tiny_disk / "run")


def test_eval_on_a_full_disk_names_the_users_path_and_keeps_the_old_set(tiny_disk, synth_dir):
    """The set is written in a temporary sibling of --out DIR: a full disk there fails with DIR/<file> named (never
    the temporary folder), exit 1, the earlier set whole and nothing left behind."""
    import os

    out = tiny_disk / "ev"
    base = [*SEQNET, "-q", "eval", "--dataset", str(synth_dir), "--method", "single", "--out", str(out)]
    assert subprocess.run(base, capture_output=True, text=True, timeout=300).returncode == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    st = os.statvfs(tiny_disk)
    with open(tiny_disk / "filler", "wb") as f:  # leave room for results.json, not for the report
        f.write(b"\0" * max(st.f_bavail * st.f_frsize - (48 << 10), 0))
    p = subprocess.run([*base, "--report"], capture_output=True, text=True, timeout=300)
    _one_line_exit_1(p, f"{out}/")
    assert ".seqnet-" not in p.stderr and ("no space left" in p.stderr or "disk full" in p.stderr), p.stderr
    assert {q.name: q.read_bytes() for q in out.iterdir()} == before
    _clean(tiny_disk)
