"""Results written into a folder the user may share with other files: one version, swapped in at once.

``eval --out DIR``, ``experiment … --out DIR``, ``benchmark … --out DIR`` and ``demo --out DIR`` write
several files (results.json, figures, report.html, caches). :func:`update_folder` makes the new version
in a temporary sibling, carries every other entry of ``DIR`` into it by hard links (a user's files keep
their inodes and bytes; nothing is copied), and swaps it in with one ``renameat2(RENAME_EXCHANGE)``: a
kill at any moment leaves the old version whole or the new one whole, never a mix, and never a user's
file lost. An output name that is already in ``DIR`` is replaced only when seqnet wrote it (listed in the
folder's manifest); otherwise the command is refused before any work (:func:`check_outputs`), unless
``overwrite``.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import stat
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path

from ..core.errors import OutputError
from ..core.log import logger
from .dirs import recover_dir, swap_dir_in
from .files import TEMP_MARK, TEMP_SUFFIX, current_umask, temp_prefix
from .ownership import MANIFEST, owned, write_manifest

MAX_CARRIED = 100_000  # entries of a folder carried into its new version (more: write the results elsewhere)


def _ours(root: Path) -> set[str]:
    return owned(root)


def _under(rel: str, name: str) -> bool:
    return rel == name or rel.startswith(name + "/")


def check_outputs(root: str | os.PathLike[str], names: Iterable[str], what: str, overwrite: bool = False) -> None:
    """Refuse (:class:`OutputError`) to write the top-level outputs ``names`` into ``root`` when one of them is
    there and holds a file seqnet did not write (its manifest does not list it), unless ``overwrite``."""
    root = Path(root)
    if root.exists() and (not root.is_dir()):
        raise OutputError(f"{root} exists and is not a folder; choose another output for the {what}")
    if overwrite or not root.is_dir():
        return
    ours = _ours(root)
    for name in names:
        entry = root / name
        if not entry.exists() and not entry.is_symlink():
            continue
        files = [entry] if not entry.is_dir() or entry.is_symlink() else [p for p in entry.rglob("*")
                                                                          if not p.is_dir() or p.is_symlink()]
        foreign = [p for p in files if str(p.relative_to(root)) not in ours]
        if foreign:
            raise OutputError(f"{foreign[0]} was not written by seqnet; refusing to replace it with the {what} "
                              "(move it away, choose another output folder, or pass --overwrite)")


def update_folder(root: str | os.PathLike[str], write: Callable[[Path], Iterable[Path]], what: str,
                  overwrite: bool = False, drop: Iterable[str] = ()) -> Path:
    """Write a new version of the folder ``root`` (module docstring): ``write(tmp)`` writes this run's outputs
    into ``tmp`` and returns the files it wrote; everything else in ``root`` is carried over, except a name in
    ``drop`` that this run did not write and seqnet did (an earlier set's output, e.g. a report this run does
    not make: it would describe another run). Call under the lock of ``root``
    (:func:`seqnet.security.locks.locked`)."""
    root = Path(os.path.realpath(root))
    recover_dir(root)
    root.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=root.parent, prefix=temp_prefix(root.name), suffix=TEMP_SUFFIX))
    try:
        tmp.chmod((root.stat().st_mode & 0o7777) if root.is_dir() else 0o777 & ~current_umask())
        written = {str(Path(p).relative_to(tmp)) for p in write(tmp)}
        names = {p.name for p in tmp.iterdir()} - {MANIFEST}
        check_outputs(root, names, what, overwrite)
        mine = _ours(root)
        gone = {n for n in set(drop) - names if n in mine and (root / n).is_file() and not (root / n).is_symlink()}
        kept, top = _carry_all(root, tmp, names | gone) if root.is_dir() else ([], set())
        ours = {f for f in mine if not any(_under(f, n) for n in names | gone)}
        write_manifest(tmp, "outputs", [tmp / f for f in sorted(written | (ours & set(kept)))])
        swap_dir_in(tmp, root)  # ``tmp`` now holds the old version (or is gone when root was new)
        _restore_newcomers(tmp, root, top | names | gone | {MANIFEST})
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return root


def _carry_all(root: Path, tmp: Path, replaced: set[str]) -> tuple[list[str], set[str]]:
    """Hard-link every entry of ``root`` that this run does not replace into ``tmp``: the relative paths of the
    files carried, and the top-level names."""
    carried: list[str] = []
    top = set()
    for entry in sorted(os.listdir(root)):
        if entry in replaced or entry == MANIFEST or (TEMP_MARK in entry and entry.endswith(TEMP_SUFFIX)):
            continue  # replaced, rewritten, or a dead run's temporary file
        _carry(root / entry, tmp / entry, entry, root, carried)
        top.add(entry)
    return carried, top


def _carry(src: Path, dst: Path, rel: str, root: Path, carried: list[str]) -> None:
    mode = os.lstat(src).st_mode
    if len(carried) >= MAX_CARRIED:
        raise OutputError(f"{root} holds more than {MAX_CARRIED} files; write the results to a folder of their own")
    if stat.S_ISDIR(mode):
        os.mkdir(dst, stat.S_IMODE(mode))
        for entry in sorted(os.listdir(src)):
            _carry(src / entry, dst / entry, f"{rel}/{entry}", root, carried)
        return
    if stat.S_ISLNK(mode):
        os.symlink(os.readlink(src), dst)
    elif stat.S_ISREG(mode):
        try:
            os.link(src, dst, follow_symlinks=False)
        except OSError as e:
            if e.errno in (errno.EXDEV, errno.EPERM, errno.EMLINK, errno.ENOTSUP):
                raise OutputError(f"{src} cannot be kept in the new version of {root} (a hard link is refused: "
                                  f"{e.strerror}); write the results to a folder of their own") from e
            raise
    else:
        raise OutputError(f"{src} is a special file that seqnet cannot carry into the new version of {root}; "
                          "write the results to a folder of their own")
    carried.append(rel)


def _restore_newcomers(old: Path, root: Path, known: set[str]) -> None:
    """Entries another program made in the old folder while the new one was written (neither carried nor
    replaced): moved into the new folder, never deleted."""
    if not old.is_dir():
        return
    for entry in sorted(os.listdir(old)):
        if entry in known or (TEMP_MARK in entry and entry.endswith(TEMP_SUFFIX)):  # a dead run's temporary file
            continue
        with contextlib.suppress(OSError):
            if not (root / entry).exists():
                os.rename(old / entry, root / entry)
                logger.warning("%s appeared while seqnet wrote %s; kept", entry, root)
