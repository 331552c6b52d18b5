"""Under ``ulimit -v`` (RLIMIT_AS) the memory check counts the address space the work reserves beyond what it
makes resident (threads' stacks and malloc arenas, the allocator's slack): what passes the check then fits."""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from seqnet.core import memory
from seqnet.core.errors import ResourceError

MIB = 1 << 20


@pytest.fixture
def limits(monkeypatch):
    """The limits stubbed: 64 GiB free, no cgroup, ``VmSize`` and torch's threads set by the test."""
    monkeypatch.delenv("SEQNET_MEMORY_MB", raising=False)
    monkeypatch.delenv("MALLOC_ARENA_MAX", raising=False)
    monkeypatch.setattr(memory, "_meminfo_available", lambda: 64 << 30)
    monkeypatch.setattr(memory, "_cgroup_available", lambda: None)
    real = resource.getrlimit

    def set_limits(soft_mib: float | None, vmsize_mib: int, threads: int) -> None:
        soft = resource.RLIM_INFINITY if soft_mib is None else int(soft_mib * MIB)
        monkeypatch.setattr(memory.resource, "getrlimit", lambda which: (soft, resource.RLIM_INFINITY)
                            if which == resource.RLIMIT_AS else real(which))
        monkeypatch.setattr(memory, "_address_space", lambda: vmsize_mib * MIB)
        monkeypatch.setattr(memory, "_threads", lambda: threads, raising=False)
    return set_limits


def test_the_report_case_is_refused_and_what_trains_passes(limits):
    """seqnet train D=4096 S_5 w=3 (needs 922 MiB beyond 263 held) at ``ulimit -v 2000000`` (1953 MiB): VmSize at
    the check 792 MiB with torch's 2 threads; it trained from a limit of 2012 MiB (bisected), so is refused: it
    passed before (1161 MiB room) and died of OOM. Admitted from 2026 MiB. With 1 thread (VmSize 784 MiB) it trained
    from 1920 MiB, admitted from 1946 MiB."""
    limits(2000000 / 1024, 792, 2)
    assert memory.reserved_bytes() == 312 * MIB
    with pytest.raises(ResourceError, match=r"training needs about 1\.2 GiB .*, 1\.1 GiB available; hint: --pca 64; "
                                            r"the binding limit is the address space \(ulimit -v\), of which 3 threads"
                                            r"'.* reserve about 312 MiB .*: raise the limit, or --threads 1 \(saves "
                                            r"about 72 MiB\)$"):
        memory.check_fits(922 * MIB, "training", "--pca 64", held=263 * MIB)
    limits(2026, 792, 2)
    memory.check_fits(922 * MIB, "training", "--pca 64", held=263 * MIB)
    limits(2000000 / 1024, 784, 1)
    memory.check_fits(922 * MIB, "training", "--pca 64", held=263 * MIB)  # --threads 1 trained at 2000000 KiB
    with pytest.raises(ResourceError, match=r"\(ulimit -v\), of which 2 threads.* raise the limit$"):
        memory.check_fits(1000 * MIB, "training", "--pca 64")  # no fewer threads to offer


def test_without_ulimit_v_the_room_is_unchanged(limits, monkeypatch):
    limits(None, 792, 8)
    assert memory.available_bytes() == 64 << 30
    monkeypatch.setenv("SEQNET_MEMORY_MB", "10")
    with pytest.raises(ResourceError, match=r"available; hint: h$"):  # no word of the address space
        memory.check_fits(20 * MIB, "x", "h")


def test_malloc_arena_max_caps_the_arenas_counted(limits, monkeypatch):
    limits(4000, 800, 4)
    assert memory.reserved_bytes() == (96 + 5 * 8 + 5 * 64) * MIB
    assert memory.available_bytes() == (4000 - 800 - 456) * MIB
    monkeypatch.setenv("MALLOC_ARENA_MAX", "2")  # the main arena and one more
    assert memory.reserved_bytes() == (96 + 5 * 8 + 64) * MIB


CHILD = r"""
import json, os, resource, sys
import torch
from seqnet.data.synth import make_synthetic
from seqnet.train.config import TrainConfig
from seqnet.train.loop import train
torch.set_num_threads(1)
ds = make_synthetic(places=200, dim=16, seed=1)
vm = int(open("/proc/self/statm").read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
resource.setrlimit(resource.RLIMIT_AS, (vm + (200 << 20), resource.RLIM_INFINITY))
try:
    train(ds, TrainConfig(epochs=1, device="cpu"), sys.argv[1])
    said = ["trained", ""]
except BaseException as e:
    said = [type(e).__name__, str(e)]
print(json.dumps(said))
"""


def test_a_training_the_address_space_cannot_hold_is_refused_at_the_check(tmp_path):
    """A tiny training (96 MiB planned) given 200 MiB of address space beyond its VmSize: the check passed
    (before) and training died of MemoryError; now the check refuses, naming ulimit -v, before any file."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(memory.__file__).parents[2]),
                                                        os.environ.get("PYTHONPATH", "")])}
    env.pop("SEQNET_MEMORY_MB", None)
    env.pop("MALLOC_ARENA_MAX", None)
    out = subprocess.run([sys.executable, "-c", CHILD, str(tmp_path / "run")], capture_output=True, text=True,
                         env=env, timeout=120)
    kind, said = json.loads(out.stdout.strip().splitlines()[-1])
    assert kind == "ResourceError" and "needs about" in said and "(ulimit -v)" in said, (kind, said, out.stderr)
    assert not (tmp_path / "run").exists()
