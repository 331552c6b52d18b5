"""Exclusive locks on outputs: a second writer is refused at once, naming the holder.

:func:`locked` holds ``fcntl.flock`` on ``<parent>/.<name>.lock`` while a command writes ``<name>``: a
killed process never leaves a stale lock (the kernel releases it), the file is removed by its holder. The
lock file is opened with ``O_NOFOLLOW`` (a planted link is refused, never followed to truncate its target)
and only a file that is empty or starts like seqnet's own (:data:`LOCK_PREFIX`) is taken over.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator
from pathlib import Path

from ..core.errors import LockedError, OutputError
from ..core.log import logger
from .inputs import nofollow_fd
from .ownership import now

LOCK_PREFIX = "PID "  # what a seqnet lock file starts with (its holder: PID, host, start, command)
_HELD: dict[Path, int] = {}  # locks this process holds (re-entrant: a stage may call another on the same dir)


def lock_file(path: Path) -> Path:
    """The lock file of directory ``path``: ``<parent>/.<name>.lock``."""
    return path.parent / f".{path.name}.lock"


@contextlib.contextmanager
def locked(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Hold the exclusive lock of directory ``path`` inside the block (the directory need not exist)."""
    import fcntl

    path = Path(path).absolute()
    if path in _HELD:
        _HELD[path] += 1
        try:
            yield path
        finally:
            _HELD[path] -= 1
        return
    lock = lock_file(path)
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
        fd = _acquire(lock, path, fcntl)
    except LockedError:
        raise
    except (OutputError, OSError) as e:  # the output's folder cannot hold a file: say which output
        why = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
        raise OutputError(f"cannot write {path}: its lock file {lock.name} cannot be made in {lock.parent} "
                          f"({why})") from e
    _HELD[path] = 1
    try:
        yield path
    finally:
        del _HELD[path]
        with contextlib.suppress(OSError):
            lock.unlink()
        os.close(fd)


def _acquire(lock: Path, path: Path, fcntl) -> int:  # noqa: ANN001 - the fcntl module
    for _ in range(100):  # retry when the file we locked was removed by its previous holder meanwhile
        fd = nofollow_fd(lock, os.O_RDWR | os.O_CREAT, 0o644, "lock file", OutputError)  # a planted link: refused
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError as err:
            holder = os.read(fd, 512).decode("utf-8", "replace").strip() or "unknown process"
            os.close(fd)
            raise LockedError(f"{path} is in use by another seqnet process ({holder}); wait for it to finish or "
                              f"choose another output (lock: {lock})") from err
        try:
            same = os.fstat(fd).st_ino == os.stat(lock).st_ino
        except FileNotFoundError:
            same = False
        if same:
            stale = os.read(fd, 512).decode("utf-8", "replace").strip()
            if stale and not stale.startswith(LOCK_PREFIX):  # a user's own file of that name: not ours to truncate
                os.close(fd)
                raise OutputError(f"{lock} exists and is not a seqnet lock file; seqnet will not overwrite it "
                                  "(move it away, or choose another output)")
            if stale:
                logger.debug("taking over the lock of %s from a process that ended (%s)", path, stale)
            # the host by os.uname (socket's gethostname on POSIX): no import while the lock is held, so a child
            # forked while another thread held an import lock cannot hang here holding it
            info = f"{LOCK_PREFIX}{os.getpid()} on {os.uname().nodename} since {now()}: {' '.join(sys.argv[:3])}"
            try:
                os.ftruncate(fd, 0)
                os.lseek(fd, 0, os.SEEK_SET)
                os.write(fd, info.encode())
            except OSError:  # e.g. a full disk: leave no lock file behind
                os.close(fd)
                with contextlib.suppress(OSError):
                    lock.unlink()
                raise
            return fd
        os.close(fd)
    raise LockedError(f"cannot lock {path}: its lock file {lock} keeps changing")  # pragma: no cover
