"""Memory estimates checked before the work: refuse what cannot fit, with the estimate and the way out.

:func:`available_bytes` is what this process may still allocate: the kernel's ``MemAvailable``, lowered
by a cgroup limit (``memory.max`` − ``memory.current``) and by ``ulimit -v`` when set: that limit is on
address space, of which the work reserves more than it makes resident (:func:`reserved_bytes`), so its room is
the limit less ``VmSize`` less that reserve. :func:`check_fits` refuses an estimate over it with a
:class:`ResourceError` (one line, exit 1) naming the estimate, what is available and the hints (under ``ulimit -v``,
also raising it and fewer threads); with ``held`` (what the process already holds, :func:`rss_bytes`) both
figures are the process's whole: its peak and what it can reach.
"""

from __future__ import annotations

import os
import resource
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from .errors import ResourceError

BLOCK_BYTES = 64 << 20
"""The one working-memory unit: every block, chunk and batch budget of the library is a stated multiple of it
(one query x reference block of distances, rows gathered or written per step, windows per batch, vectors added
to an index per call). It bounds what a step holds beside its inputs, whatever their size; docs/scale.md
lists each use. Array thresholds (memory maps streamed, arrays spilled) and the memory check are separate
settings with their own environment overrides (``SEQNET_RESIDENT_MB``, ``SEQNET_SPILL_MB``,
``SEQNET_MEMORY_MB``)."""

CGROUP = Path("/sys/fs/cgroup")


def _meminfo_available() -> int | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _cgroup_available() -> int | None:
    try:
        limit = (CGROUP / "memory.max").read_text().strip()
        if limit == "max":
            return None
        free = int(limit) - int((CGROUP / "memory.current").read_text().strip())
    except (OSError, ValueError):
        return None
    return free + _reclaimable()


def _reclaimable() -> int:
    """The cgroup's inactive page cache (``memory.stat`` ``inactive_file``): counted in ``memory.current`` but
    given back under pressure (what kubelet and docker subtract too)."""
    try:
        for line in (CGROUP / "memory.stat").read_text().splitlines():
            key, _, value = line.partition(" ")
            if key == "inactive_file":
                return int(value)
    except (OSError, ValueError):
        pass
    return 0


def available_bytes() -> int | None:
    """Bytes this process may still allocate (None: unknown, e.g. not Linux)."""
    found = _limits()
    return max(0, min(found.values())) if found else None


def _limits() -> dict[str, int]:
    """Each known limit's room, by name; ``"address space"`` (``ulimit -v``) net of :func:`reserved_bytes`."""
    found = {k: b for k, b in (("memory", _meminfo_available()), ("cgroup", _cgroup_available())) if b is not None}
    soft = resource.getrlimit(resource.RLIMIT_AS)[0]
    if soft != resource.RLIM_INFINITY:
        found["address space"] = soft - _address_space() - reserved_bytes()
    env = os.environ.get("SEQNET_MEMORY_MB")  # an explicit budget (a shared machine, a test)
    if env:
        found["budget"] = int(float(env) * 2**20)
    return found


ARENA_BYTES = 64 << 20
"""Address space a thread's own glibc malloc arena reserves (``HEAP_MAX_SIZE`` on 64-bit; mapped but mostly
``PROT_NONE``, so never resident, yet counted against ``ulimit -v``): a new thread that allocates gets one, up to
``MALLOC_ARENA_MAX`` arenas (default 8 per CPU) with the main one."""
STACK_BYTES = 8 << 20  # a thread's stack: glibc's default is the soft ``ulimit -s``, 8 MiB by default
RESERVE_BASE_BYTES = 96 << 20
"""Address space beyond the resident estimate besides threads: untouched pages of allocations (calloc, the
heap's free part), libraries mapped on first use. Measured 2026-12-05 (torch 2.13 CPU, ``seqnet train --epochs 1
--device cpu``, the smallest ``ulimit -v`` that trains, bisected in 7 MiB steps, less ``VmSize`` at the check
and the plan's ``train_bytes``): 203-214 MiB at ``--threads 1``, 271-298 MiB at 2 and 400 MiB at 4 (D = 4096
and 2048, batch 16 and 4), i.e. 72 MiB a thread over the ``n + 1`` threads training starts (torch's ``n - 1``
workers and two more) and 40-70 MiB besides: :func:`reserved_bytes` is 240 / 312 / 456 MiB there."""


def reserved_bytes(n: int | None = None) -> int:
    """Address space the work about to run reserves beyond the resident memory it is planned to use (what
    ``ulimit -v`` counts and a resident estimate does not): :data:`RESERVE_BASE_BYTES` and, for each of the
    ``n + 1`` threads it starts (``n``: torch's intra-op threads, default the current number, or the usable CPUs
    where torch is not loaded), a stack and a malloc arena (:data:`ARENA_BYTES`; fewer under
    ``MALLOC_ARENA_MAX``)."""
    threads = (n or _threads()) + 1
    cap = os.environ.get("MALLOC_ARENA_MAX", "")
    arenas = min(threads, max(0, int(cap) - 1)) if cap.isdigit() else threads  # the main arena is one of them
    return RESERVE_BASE_BYTES + threads * STACK_BYTES + arenas * ARENA_BYTES


def _threads() -> int:
    torch = sys.modules.get("torch")
    if torch is not None and hasattr(torch, "get_num_threads"):
        return max(1, int(torch.get_num_threads()))
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def _address_space() -> int:
    try:
        return int(Path("/proc/self/statm").read_text().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError):
        return 0


def gib(n: float) -> str:
    return f"{n / 2**30:.1f} GiB"


def check_fits(needed: int, what: str, hints: str, held: int = 0, free: int | None = None) -> None:
    """Refuse ``needed`` more bytes for ``what`` when more than ``free`` (default :func:`available_bytes`;
    nothing when unknown). With ``held``, the bytes the process already holds, the message names the whole:
    a peak of ``held + needed`` against ``held + free`` available."""
    free = available_bytes() if free is None else free
    if free is not None and needed > free:
        of = f" ({gib(held)} held by this process before it + {gib(needed)} more)" if held else ""
        raise ResourceError(f"{what} needs about {gib(held + needed)} of memory{of}, {gib(held + free)} available; "
                            f"hint: {hints}{_address_space_hint()}")


def _address_space_hint() -> str:
    """Where ``ulimit -v`` is the limit that binds: what else lowers the need (a higher limit, fewer threads)."""
    found = _limits()
    room = found.get("address space")
    if room is None or room > min(found.values()):
        return ""
    n = _threads()
    fewer = f", or --threads 1 (saves about {human_bytes(reserved_bytes(n) - reserved_bytes(1))})" if n > 1 else ""
    return (f"; the binding limit is the address space (ulimit -v), of which {n + 1} threads' stacks and malloc "
            f"arenas and the allocator reserve about {human_bytes(reserved_bytes())} beyond the memory used: raise "
            f"the limit{fewer}")


BASE_BYTES = 258 << 20
"""Resident memory of a Python process with torch and seqnet imported (VmRSS of ``python -c "import torch,
seqnet.train, seqnet.cli"``: 258 MiB measured 2026-12-04, torch 2.13 CPU): what :func:`rss_bytes` says where
the process's own figure cannot be read."""


def rss_bytes() -> int:
    """Bytes this process holds now: ``VmRSS`` of ``/proc/self/status``; else its peak so far (``ru_maxrss``,
    KiB on Linux, bytes on macOS); else :data:`BASE_BYTES`."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    peak = int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
    return peak * (1 if sys.platform == "darwin" else 1024) if peak > 0 else BASE_BYTES


WORKSPACE_BYTES = 4 * BLOCK_BYTES  # a few query x reference blocks in flight (search.knn.DEFAULT_BLOCK_BYTES each)


def workspace_bytes(n_query: int, n_ref: int) -> int:
    """The search blocks in flight: :data:`WORKSPACE_BYTES`, or less when all scores are smaller (tiny data)."""
    return min(WORKSPACE_BYTES, 16 * n_query * n_ref + (16 << 20))


def model_bytes(models: Iterable[Any]) -> int:
    """Bytes of the parameters of torch modules ``models``."""
    return sum(p.numel() * p.element_size() for m in models for p in m.parameters())


def described_bytes(n_query: int, n_ref: int, dims: Iterable[int], resident_cap: int) -> int:
    """Bytes of the descriptors one evaluation holds: each of ``dims`` (one per sequence descriptor the methods
    compute) in float32 for every query item, and for the reference up to ``resident_cap`` each (larger ones go
    to a spill file: :mod:`seqnet.core.memmaps`)."""
    return sum(4 * n_query * d + min(4 * n_ref * d, resident_cap) for d in dims)


SPACE_MARGIN = 16 * 2**20
HDF5_OVERHEAD = 128 << 10  # an HDF5 file's metadata beyond its data, with room (check_space before h5py writes)


def check_space(folder: Path, needed: int, what: str, largest: int | None = None) -> None:
    """Refuse to start writing ``needed`` bytes into ``folder`` (one line, exit 1) when the file system
    has less free, or one file of ``largest`` bytes (default: half) when the process's file size limit
    (``ulimit -f``) is lower: a library that hits either mid-write may not fail cleanly (HDF5, memory maps)."""
    import shutil

    limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    largest = needed // 2 if largest is None else largest
    if limit != resource.RLIM_INFINITY and largest > limit:
        raise ResourceError(f"{folder}: {what} make a file of about {human_bytes(largest)}, over this process's "
                            f"file size limit of {human_bytes(limit)} (ulimit -f); hint: raise the limit")
    try:
        free = shutil.disk_usage(folder).free
    except OSError:
        return
    if free < needed + SPACE_MARGIN:
        raise ResourceError(f"{folder}: {what} need about {human_bytes(needed + SPACE_MARGIN)}, only "
                            f"{human_bytes(free)} free; hint: free some space or write the output elsewhere")


def human_bytes(n: float) -> str:
    """A byte count in bytes under 1 KiB, KiB under 1 MiB, MiB under 1 GiB, else GiB (one decimal), the unit
    chosen on the rounded value (2**20 - 1 bytes is "1 MiB", never "1024 KiB")."""
    if round(n) < 2**10:
        return f"{n:.0f} B"
    if round(n / 2**10) < 2**10:
        return f"{n / 2**10:.0f} KiB"
    return f"{n / 2**20:.0f} MiB" if round(n / 2**20) < 2**10 else f"{n / 2**30:.1f} GiB"
