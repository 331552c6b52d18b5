"""Who may write where: exclusive locks on run and dataset directories, and manifests of what seqnet wrote.

* :func:`locked` holds an exclusive lock on a directory while a command writes it: a second writer
  (another process) is refused at once with a one-line :class:`LockedError` naming the holder. The
  lock is ``fcntl.flock`` on the file ``<parent>/.<name>.lock``, so a killed process never leaves
  a stale lock behind (the kernel releases it); the file itself is removed by its holder.
* A *manifest* (``.seqnet-manifest.json`` inside an output directory) lists the files a seqnet run
  wrote there. :func:`remove_owned_dir` deletes a directory only when every file in it is listed
  (or, for directories older than manifests, matches what seqnet writes): a user's file is never lost.
"""

from __future__ import annotations

import contextlib
import datetime
import json
import os
import shutil
import socket
import sys
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from .._version import __version__
from .errors import LockedError, OutputError
from .utils import logger

MANIFEST = ".seqnet-manifest.json"
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
    lock.parent.mkdir(parents=True, exist_ok=True)
    fd = _acquire(lock, path, fcntl)
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
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
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
            if stale:
                logger.debug("taking over the lock of %s from a process that ended (%s)", path, stale)
            os.ftruncate(fd, 0)
            os.lseek(fd, 0, os.SEEK_SET)
            info = f"PID {os.getpid()} on {socket.gethostname()} since {_now()}: {' '.join(sys.argv[:3])}"
            os.write(fd, info.encode())
            return fd
        os.close(fd)
    raise LockedError(f"cannot lock {path}: its lock file {lock} keeps changing")  # pragma: no cover


def _now() -> str:
    return datetime.datetime.now().isoformat(timespec="seconds")


def write_manifest(root: str | os.PathLike[str], kind: str, files: Iterable[str | os.PathLike[str]]) -> Path:
    """Record in ``root/.seqnet-manifest.json`` that this seqnet ``kind`` of run wrote ``files`` (under ``root``)."""
    from .files import write_json_atomic

    root = Path(root)
    rel = sorted({str(Path(f).absolute().relative_to(root.absolute())) for f in files})
    return write_json_atomic(root / MANIFEST, {"kind": kind, "seqnet_version": __version__, "written": _now(),
                                               "files": rel})


def read_manifest(root: Path) -> dict | None:
    """The manifest of ``root``, or None when it has none (or an unreadable one)."""
    try:
        data = json.loads((root / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and isinstance(data.get("files"), list) else None


def foreign_files(root: Path, known: Callable[[str], bool] | None = None) -> list[str]:
    """Files under ``root`` (relative paths) that seqnet did not write: not in its manifest, and
    (for a directory without a manifest) not accepted by ``known``."""
    manifest = read_manifest(root)
    listed = set(manifest["files"]) if manifest else set()
    out = []
    for p in sorted(root.rglob("*")):
        if p.is_dir() and not p.is_symlink():
            continue
        rel = str(p.relative_to(root))
        if rel == MANIFEST or rel in listed or (manifest is None and known is not None and known(rel)):
            continue
        out.append(rel)
    return out


def check_replaceable(root: str | os.PathLike[str], what: str, known: Callable[[str], bool] | None = None) -> None:
    """Raise :class:`OutputError` unless everything in directory ``root`` was written by seqnet."""
    root = Path(root)
    if root.exists() and not root.is_dir():
        raise OutputError(f"{root} exists and is not a directory; choose another output for the {what}")
    if root.is_symlink():
        raise OutputError(f"{root} is a symbolic link; seqnet does not replace links (choose another output)")
    if not root.exists():
        return
    foreign = foreign_files(root, known)
    if foreign:
        raise OutputError(f"{root} holds {len(foreign)} file(s) seqnet did not write (first: {foreign[0]}); "
                          f"refusing to replace it with a new {what} (choose another output or move them)")


def remove_owned_dir(root: str | os.PathLike[str], what: str, known: Callable[[str], bool] | None = None) -> None:
    """Delete directory ``root`` after :func:`check_replaceable` (nothing when it does not exist)."""
    root = Path(root)
    check_replaceable(root, what, known)
    if root.exists():
        shutil.rmtree(root)


def swap_dir_in(new: Path, root: Path) -> None:
    """Rename the directory ``new`` onto ``root`` (a sibling); an existing ``root`` (already checked
    replaceable) is moved aside first and deleted only once ``new`` is in place, else put back."""
    old: Path | None = None
    if root.exists():
        old = Path(tempfile.mkdtemp(dir=root.parent, prefix=f".{root.name}.", suffix=".old"))
        old.rmdir()
        root.rename(old)
    try:
        new.rename(root)
    except OSError:
        if old is not None:
            old.rename(root)
            old = None
        raise
    finally:
        if old is not None and old.exists():
            shutil.rmtree(old, ignore_errors=True)
