"""Running a reader of untrusted bytes in a child process: a crash, hang or allocation bomb ends the child.

Some libraries cannot be trusted with a stranger's file: libhdf5 and FAISS allocate what a header
declares and can crash the interpreter on malformed input. Their readers run here, in a child
Python (:func:`run_child`) that:

* imports seqnet from where this process did, never from the current directory (a ``seqnet/``
  folder there is not imported), isolated (``-I``: no ``PYTHON*`` variables, no user site, neither the
  current nor the script's directory on the path);
* limits its own address space (``RLIMIT_AS``) and CPU time first thing, writes no files
  (``RLIMIT_FSIZE`` 0), makes no core dump, runs in ``/`` with one BLAS thread, and loads no HDF5
  filter plugin (``HDF5_PLUGIN_PRELOAD=::``);
* is killed after ``timeout`` seconds.

It answers one JSON line (its result, or ``{"error": ...}`` for a refusal) and then the bytes the
result announces; a child that dies (signal, memory, time) becomes ``error`` saying so, in one line.
:func:`python_command` is also how ``seqnet benchmark timing`` starts its workers.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import sys
import tempfile
import threading
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from ..core.errors import DatasetError
from .inputs import ErrorType

if TYPE_CHECKING:
    import subprocess

BASE_MEMORY = 768 << 20  # the child's interpreter, numpy and the library itself
MAX_HEADER = 1 << 30
BASE_SECONDS, BYTES_PER_SECOND = 30.0, 5e6  # a child's time: start-up under load, then its file at a slow 5 MB/s


def time_bound(size: int) -> float:
    """Seconds a sandboxed reader may take on a file of ``size`` bytes before it is killed (a damaged file can
    make a library loop: the fuzzer found libhdf5 spinning on a 6 KiB file)."""
    return BASE_SECONDS + size / BYTES_PER_SECOND
_BOOT = """import sys, json
mem, cpu, paths = json.loads(sys.argv[1])
if mem:  # a reader of untrusted bytes: bounded memory and time, no file written, no core dump
    import resource
    for limit, value in ((resource.RLIMIT_AS, mem), (resource.RLIMIT_CPU, cpu or -1), (resource.RLIMIT_FSIZE, 0),
                         (resource.RLIMIT_CORE, 0)):
        resource.setrlimit(limit, (value, value))
sys.path[:] = paths
"""


def import_paths() -> list[str]:
    """Where the child imports from: seqnet's own folder first, then this interpreter's absolute paths, never
    the current directory (``''`` or its absolute name)."""
    here = str(Path(__file__).resolve().parents[2])
    cwd = os.getcwd()
    rest = [p for p in sys.path if p and os.path.isabs(p) and os.path.realpath(p) != os.path.realpath(cwd)]
    return [here, *(p for p in rest if p != here)]


def python_command(code: str, memory: int | None = None, cpu_seconds: int | None = None) -> list[str]:
    """``[python, -I, -c, ...]`` running ``code`` with seqnet importable as in this process and the current
    directory off the import path; with ``memory`` (and ``cpu_seconds``) the child limits itself first and
    can write no file."""
    limits = [memory or 0, cpu_seconds or 0, import_paths()]
    return [sys.executable, "-I", "-c", _BOOT + code, json.dumps(limits)]


def child_env() -> dict[str, str]:
    """The child's environment: this one without ``PYTHON*`` variables, one BLAS thread, no HDF5 plugins."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON")}
    env.update(OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1", HDF5_PLUGIN_PRELOAD="::",
               HDF5_USE_FILE_LOCKING="FALSE")
    return env


@contextlib.contextmanager
def run_child(op: str, request: dict[str, Any], what: str, memory: int, timeout: float,
              error: ErrorType = DatasetError, fds: Sequence[int] = ()) -> Iterator[tuple[dict[str, Any], IO[bytes]]]:
    """Run the reader ``op`` of :mod:`seqnet.security.child` on ``request`` in a limited child (module
    docstring); yields its answer and the stream of the bytes the answer announces. ``error`` names ``what``
    when the child refuses the input, dies or overruns ``timeout`` seconds."""
    import subprocess  # here: a reader run, not every import of the readers

    code = "from seqnet.security.child import main\nmain()\n"
    cmd = python_command(code, BASE_MEMORY + memory, int(timeout) + 1)
    with tempfile.TemporaryFile() as err:
        proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=err, cwd="/",
                                env=child_env(), pass_fds=tuple(fds), start_new_session=True)
        timer = threading.Timer(timeout, _kill, (proc,))
        timer.start()
        try:
            assert proc.stdin is not None and proc.stdout is not None
            proc.stdin.write(json.dumps({"op": op, **request}).encode() + b"\n")
            proc.stdin.close()
            answer = _answer(proc, err, what, error, timer, timeout)
            yield answer, proc.stdout
        finally:
            timer.cancel()
            _kill(proc)
            proc.wait()
            proc.stdout.close()  # type: ignore[union-attr]


def _kill(proc: subprocess.Popen) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)


def _answer(proc: subprocess.Popen, err: IO[bytes], what: str, error: ErrorType, timer: threading.Timer,
            timeout: float) -> dict[str, Any]:
    """The child's JSON answer line; ``error`` when it refused the input or ended without answering."""
    line = proc.stdout.readline(MAX_HEADER)  # type: ignore[union-attr]
    try:
        answer = json.loads(line) if line.endswith(b"\n") else None
    except ValueError:
        answer = None
    if isinstance(answer, dict) and isinstance(answer.get("error"), str):
        raise error(answer["error"])
    if isinstance(answer, dict) and isinstance(answer.get("failed"), str):
        raise error(f"cannot read {what}: the reader failed on it ({answer['failed']})")
    if isinstance(answer, dict):
        return answer
    code = proc.wait()
    raise error(f"cannot read {what}: {_death(code, err, timer, timeout)}")


def _death(code: int, err: IO[bytes], timer: threading.Timer, timeout: float) -> str:
    """Why the child ended without answering, in words."""
    err.seek(0)
    tail = " ".join(err.read()[-2000:].decode("utf-8", "replace").split())
    if code < 0 and not timer.is_alive() and -code == signal.SIGKILL:
        return f"reading it took longer than {timeout:.0f} s (a hostile or damaged file?)"
    if code < 0:
        name = signal.Signals(-code).name if -code in signal.valid_signals() else str(-code)
        return f"the reader crashed on it ({name}): the file is malformed"
    if "MemoryError" in tail or "memory" in tail.lower():
        return "reading it needs more memory than its size allows (a declared size beyond the file's bytes?)"
    return f"the reader failed ({tail[-300:] or f'exit {code}'})"


def answer(out: IO[bytes], result: dict[str, Any]) -> None:
    """The child's side: write its JSON answer line (the bytes it announces follow it)."""
    out.write(json.dumps(result).encode() + b"\n")
