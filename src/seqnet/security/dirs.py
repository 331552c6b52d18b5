"""Directory outputs written whole: a temporary sibling swapped in at once, repaired after any crash.

:func:`write_dir` fills a temporary sibling (``.<name>.seqnet-XXXXXXXX.tmp``) and swaps it in with one
``renameat2(RENAME_EXCHANGE)`` (:func:`swap_dir_in`); :func:`recover_dir` and :func:`remove_dead_temps`
remove what a killed writer left, touching only names that carry seqnet's mark; :func:`read_consistent`
reads a directory as one version.
"""

from __future__ import annotations

import errno
import os
import shutil
import sys
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TypeVar

from ..core.log import logger
from .files import TEMP_SUFFIX, current_umask, in_place_of, temp_prefix

T = TypeVar("T")


def write_dir(root: Path, write: Callable[[Path], None]) -> Path:
    """The one way a directory output is written: ``write(tmp)`` fills a temporary sibling, which is then
    swapped in whole (:func:`swap_dir_in`); an OS error names the user's ``root``, not the temporary
    folder. Call under ``root``'s lock, after :func:`recover_dir` and the replaceability checks."""


    root.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=root.parent, prefix=temp_prefix(root.name), suffix=TEMP_SUFFIX))
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
    old = old_dir(root)
    if old.is_dir() and not old.is_symlink():  # a dead run's, by its marked name
        shutil.rmtree(old, ignore_errors=True)
    root.rename(old)
    try:
        new.rename(root)
    except OSError:
        old.rename(root)
        raise
    shutil.rmtree(old, ignore_errors=True)


def old_dir(root: Path) -> Path:
    """Where :func:`swap_dir_in` moves the old ``root`` aside when it cannot exchange: a name carrying
    seqnet's mark (``.<name>.seqnet-old``), so a user's own ``.<name>.old`` is never taken for it."""
    return root.parent / f"{temp_prefix(root.name)}old"


def marked_temps(out: Path) -> list[Path]:
    """The temporary files and folders seqnet made beside ``out`` (``.<name>.seqnet-*.tmp``, never a link):
    only what carries that mark is removed as a dead run's."""
    prefix = temp_prefix(out.name)
    try:
        names = os.listdir(out.parent)
    except OSError:
        return []
    return [out.parent / n for n in sorted(names) if n.startswith(prefix) and n.endswith(TEMP_SUFFIX)
            and not (out.parent / n).is_symlink()]


def remove_dead_temps(outputs: Iterable[Path]) -> None:
    """Remove the temporary files (:func:`marked_temps`, :func:`seqnet.security.files.atomic_path`) that killed
    writers of ``outputs`` left beside them. Call under the outputs' lock: no live writer owns them."""
    for out in outputs:
        for tmp in marked_temps(out):
            if tmp.is_file():
                logger.debug("removing %s, left by a run that ended", tmp)
                tmp.unlink(missing_ok=True)


def recover_dir(root: Path) -> None:
    """Repair what a killed writer of ``root`` left (call under its lock, so no writer is alive): an
    interrupted :func:`swap_dir_in` (the old directory moved aside, the new one not in place) is undone,
    a leftover old directory and the temporary directories of dead runs (:func:`marked_temps`) removed; only
    names carrying seqnet's mark are touched."""
    old = old_dir(root)
    if old.is_dir() and not old.is_symlink() and not root.exists() and not root.is_symlink():
        logger.info("restoring %s from an interrupted replacement (%s)", root, old.name)
        old.rename(root)
    elif old.is_dir() and not old.is_symlink():
        shutil.rmtree(old, ignore_errors=True)
    for tmp in marked_temps(root):
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
