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
import errno
import json
import os
import shutil
import socket
import sys
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import TypeVar

from .._version import __version__
from .errors import LockedError, OutputError
from .utils import logger

T = TypeVar("T")
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
            info = f"PID {os.getpid()} on {socket.gethostname()} since {_now()}: {' '.join(sys.argv[:3])}"
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


def write_dir(root: Path, write: Callable[[Path], None]) -> Path:
    """The one way a directory output is written: ``write(tmp)`` fills a temporary sibling, which is then
    swapped in whole (:func:`swap_dir_in`); an OS error names the user's ``root``, not the temporary
    folder. Call under ``root``'s lock, after :func:`recover_dir` and the replaceability checks."""
    from .files import current_umask, in_place_of

    root.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=root.parent, prefix=f".{root.name}.", suffix=".tmp"))
    try:
        tmp.chmod(0o777 & ~current_umask())  # mkdtemp makes it 0700; a plain mkdir would not
        try:
            write(tmp)
        except OSError as e:
            raise in_place_of(e, tmp, root) from e
        swap_dir_in(tmp, root)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return root


def swap_dir_in(new: Path, root: Path) -> None:
    """Put the directory ``new`` in place of ``root`` (a sibling) so that ``root`` is never missing: an
    existing ``root`` (already checked replaceable) is exchanged with ``new`` in one atomic
    ``renameat2(RENAME_EXCHANGE)`` and then deleted; where the file system cannot exchange, it is moved
    aside, ``new`` renamed in, and an interruption in between is repaired by the next writer
    (:func:`recover_dir`)."""
    if not root.exists():
        new.rename(root)
        return
    if exchange(new, root):
        shutil.rmtree(new, ignore_errors=True)  # ``new`` now holds the old directory
        return
    old = root.parent / f".{root.name}.old"
    if old.exists():
        shutil.rmtree(old, ignore_errors=True)
    root.rename(old)
    try:
        new.rename(root)
    except OSError:
        old.rename(root)
        raise
    shutil.rmtree(old, ignore_errors=True)


def remove_dead_temps(outputs: Iterable[Path]) -> None:
    """Remove the temporary files (``.<name>.*.tmp``, :func:`seqnet.core.files.atomic_path`) that killed
    writers of ``outputs`` left beside them. Call under the outputs' lock: no live writer owns them."""
    for out in outputs:
        for tmp in out.parent.glob(f".{out.name}.*.tmp"):
            if tmp.is_file():
                logger.debug("removing %s, left by a run that ended", tmp)
                tmp.unlink(missing_ok=True)


def recover_dir(root: Path) -> None:
    """Repair what a killed writer of ``root`` left (call under its lock, so no writer is alive): an
    interrupted :func:`swap_dir_in` (the old directory moved aside, the new one not in place) is undone,
    a leftover old directory and the temporary directories of dead runs (``.<name>.*.tmp``) removed."""
    old = root.parent / f".{root.name}.old"
    if old.is_dir() and not root.exists():
        logger.info("restoring %s from an interrupted replacement (%s)", root, old.name)
        old.rename(root)
    elif old.is_dir():
        shutil.rmtree(old, ignore_errors=True)
    for tmp in root.parent.glob(f".{root.name}.*.tmp"):
        if tmp.is_dir():
            logger.debug("removing %s, left by a run that ended", tmp)
            shutil.rmtree(tmp, ignore_errors=True)


def read_consistent(root: Path, read: Callable[[], T], error: type[Exception]) -> T:
    """``read()`` of the directory ``root`` as one version: a writer that replaced ``root`` meanwhile
    (its inode changed) makes the read start again on the new version (a reader never mixes two)."""
    for _ in range(3):
        try:
            before = os.stat(root).st_ino
        except FileNotFoundError:
            return read()  # nothing there: the reader's own error names it
        try:
            out = read()
        except (OSError, error):
            if _inode(root) != before:
                continue
            raise
        if _inode(root) == before:
            return out
    raise error(f"{root} was replaced three times while it was read; try again once its writer is done")


def _inode(path: Path) -> int | None:
    try:
        return os.stat(path).st_ino
    except FileNotFoundError:
        return None


def exchange(a: Path, b: Path) -> bool:
    """Atomically exchange two paths (Linux ``renameat2(RENAME_EXCHANGE)``); False where unsupported."""
    import ctypes
    import ctypes.util

    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    if fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EPERM, errno.EXDEV):
        return False
    raise OSError(err, os.strerror(err), str(b))
