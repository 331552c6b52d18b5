"""What every command shares at run time: log level, progress bars, thread count, warnings, errors."""

from __future__ import annotations

import argparse
import contextlib
import io
import logging
import os
import sys
import warnings
from collections.abc import Callable, Iterator
from typing import Any

from ..core.errors import SeqnetError
from ..core.log import logger
from ..core.progress import close_all, progress_mode
from ..security.files import os_error
from ..security.text import shown
from .common import positive_int


def add_runtime_options(p: argparse.ArgumentParser, top: bool) -> None:
    """``-v/-q``, ``--progress/--no-progress`` and ``--threads``, before or after the command name."""
    default = None if top else argparse.SUPPRESS  # a command's parser must not reset what came before it
    options = [
        (("-v", "--verbose"), {"action": "store_true", "default": False if top else default,
                               "help": "also log debug messages (e.g. every training epoch)"}),
        (("-q", "--quiet"), {"action": "store_true", "default": False if top else default,
                             "help": "only log warnings and errors"}),
        (("--progress",), {"dest": "progress", "action": "store_true", "default": default,
                           "help": "show progress bars even when stderr is not a terminal"}),
        (("--no-progress",), {"dest": "progress", "action": "store_false", "default": default,
                              "help": "never show progress bars (default: only on a terminal)"}),
        (("--threads",), {"type": positive_int, "default": default, "metavar": "N",
                          "help": "CPU threads for torch (default: torch's)"}),
    ]
    for flags, kwargs in options:
        if not any(f in p._option_string_actions for f in flags):  # a command may define its own
            p.add_argument(*flags, **kwargs)


class _StderrHandler(logging.StreamHandler):
    """Log handler that writes to whatever ``sys.stderr`` is at the time (pytest's capsys swaps it)."""

    def __init__(self) -> None:
        super().__init__(sys.stderr)

    @property  # type: ignore[override]
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value) -> None:  # the base class assigns it; always follow sys.stderr instead
        pass


class _EscapedStdout(io.TextIOBase):
    """``sys.stdout`` while a command runs: what it prints (tables, names read from files) with control
    characters escaped, line breaks and tabs kept."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner

    def write(self, text: str) -> int:
        self.inner.write("\n".join("\t".join(shown(c) for c in line.split("\t")) for line in text.split("\n")))
        return len(text)

    def flush(self) -> None:
        self.inner.flush()

    def isatty(self) -> bool:
        return self.inner.isatty()

    def fileno(self) -> int:
        return self.inner.fileno()


class _Escaped(logging.Formatter):
    """Log lines with control characters escaped (a file name cannot move the cursor or fake a line)."""

    def format(self, record: logging.LogRecord) -> str:
        return "\n".join(shown(line) for line in super().format(record).split("\n"))


def _blas_threads(threads: int | None) -> contextlib.AbstractContextManager:
    """NumPy's BLAS (OpenBLAS: the per-frame GEMVs of :mod:`seqnet.core.gemv`) on ``threads`` threads too."""
    if not threads:
        return contextlib.nullcontext()
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=threads, user_api="blas")


@contextlib.contextmanager
def runtime(args: argparse.Namespace) -> Iterator[None]:
    """Logging to stderr, progress mode, thread count and held-back warnings for one command. torch is not
    imported here: when it is not loaded yet, its thread count is set through ``OMP_NUM_THREADS`` (read when
    it loads), so a value a stage refuses (``--method nosuch``) is refused before torch is imported."""
    level = logging.DEBUG if args.verbose else logging.WARNING if args.quiet else logging.INFO
    handler = _StderrHandler()
    handler.setFormatter(_Escaped("%(message)s"))
    old_level = logger.level
    logger.addHandler(handler)
    logger.setLevel(level)
    threads = args.threads or getattr(args, "default_threads", None)
    restore = _set_threads(threads)
    stdout, sys.stdout = sys.stdout, _EscapedStdout(sys.stdout)
    try:
        with _blas_threads(threads), progress_mode(args.progress), warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("default")
            yield
        for message in dict.fromkeys(f"{w.category.__name__}: {w.message}" for w in caught):
            logger.debug("warning: %s", " ".join(message.split()))
    finally:
        sys.stdout = stdout
        restore()
        logger.removeHandler(handler)
        logger.setLevel(old_level)


def _set_threads(threads: int | None) -> Callable[[], None]:
    """torch's intra-op threads for one command (``torch.set_num_threads`` when torch is loaded, else
    ``OMP_NUM_THREADS`` before it loads); returns what restores the previous setting."""
    torch = sys.modules.get("torch")
    if torch is not None:
        old = torch.get_num_threads()
        if threads:
            torch.set_num_threads(threads)
        return lambda: torch.set_num_threads(old)
    old_env = os.environ.get("OMP_NUM_THREADS")
    if threads:
        os.environ["OMP_NUM_THREADS"] = str(threads)

    def restore() -> None:
        if old_env is None:
            os.environ.pop("OMP_NUM_THREADS", None)
        else:
            os.environ["OMP_NUM_THREADS"] = old_env

    return restore


def check_no_empty_values(args: argparse.Namespace) -> None:
    """An empty argument (``--json ""``, ``synth ""``, ``--method ""``) is an error, never "the default"."""
    for key, value in vars(args).items():
        values = value if isinstance(value, list) else [value]
        if any(isinstance(v, str) and not v.strip() for v in values):
            from ..core.errors import ConfigError

            raise ConfigError(f"{key.replace('_', '-')}: empty value {value!r}; give a non-empty value or leave the "
                              "option out")


def one_line(text: object) -> str:
    """``text`` on one line (runs of whitespace, line breaks included, become one space)."""
    return " ".join(str(text).split())


def report_error(command: str | None, e: BaseException, trace: BaseException | None = None) -> int:
    """Print ``e`` as one line on stderr (bars cleared first; control characters from file names escaped);
    return the exit code. ``trace``: an unexpected exception whose traceback is printed first (``-v``).

    Under torchrun, an error another rank reports too (``e.reported_elsewhere``: rank 0's, copied to
    every rank) is not printed again, and the other errors of ranks > 0 name their rank."""
    close_all()
    if trace is not None:
        import traceback

        traceback.print_exception(trace, file=sys.stderr)
    quiet = bool(getattr(e, "reported_elsewhere", False))
    if sys.stderr.isatty() and not quiet:
        sys.stderr.write("\r\x1b[K")
    if isinstance(e, KeyboardInterrupt):
        print(f"seqnet {command}: interrupted{shown(str(getattr(e, 'seqnet_hint', '')))}", file=sys.stderr)
        return 130
    if isinstance(e, OSError):
        e = os_error(e)
    elif isinstance(e, MemoryError):
        e = _memory_error(e)
    prefix = f"seqnet {command}: error: " if command else ""
    if not quiet:
        print(prefix + _rank() + shown(one_line(e)), file=sys.stderr)
    return int(getattr(e, "exit_code", 2))


def _rank() -> str:
    """``"rank N: "`` in a process of a distributed run other than rank 0 (torchrun's variables), else ``""``."""
    rank, size = os.environ.get("RANK", "0"), os.environ.get("WORLD_SIZE", "1")
    return f"rank {rank}: " if size not in ("", "0", "1") and rank not in ("", "0") else ""


_MEMORY = ("can't allocate memory", "cannot allocate memory", "out of memory", "failed to allocate", "bad_alloc",
           "failed to map segment")


def is_allocation_error(e: BaseException) -> bool:
    """Whether an exception is an allocator running out of memory (torch's CPU or CUDA allocator, a C++
    ``std::bad_alloc``, a shared library that cannot be mapped under ``ulimit -v``)."""
    text = str(e).lower()
    return any(m in text for m in _MEMORY)


def classify(e: Exception) -> BaseException:
    """What the CLI reports for an exception that is not a :class:`SeqnetError`: running out of memory (exit 1),
    a write cut short by a full disk (exit 1), an OS error (:func:`seqnet.security.files.os_error`), or an
    internal error (a bug: one line, exit 2; ``-v`` shows the traceback)."""
    from ..core.errors import ResourceError
    from ..security.files import os_error, short_write

    if isinstance(e, (RuntimeError, OSError, ImportError)) and is_allocation_error(e):
        return MemoryError(one_line(e))
    if short_write(e):
        return ResourceError("disk full while writing an output (or a file size limit, ulimit -f); hint: check the "
                             "free space, or write the output elsewhere")
    if isinstance(e, OSError):
        return os_error(e)
    return SeqnetError(f"internal error ({type(e).__name__}: {one_line(e)[:300]}); this is a bug in seqnet, please "
                       "report it (-v prints the traceback)")


def _memory_error(e: MemoryError) -> SeqnetError:
    from ..core.errors import ResourceError

    detail = f" ({one_line(e)})" if str(e) else ""
    return ResourceError(f"out of memory{detail}; hint: smaller inputs, fewer threads or a smaller --batch-size")
