"""What a pipeline command (``demo``, ``benchmark``, ``experiment``) writes into its output folder: one
version, replacing only what that command wrote there.

* :func:`check_outputs_of`, before any work: every output name already in the folder must have been
  written there by the same command (``kind``, e.g. ``"demo"``), as the folder's record
  (:data:`RECORD`: the command and the digests of the files of each output) says. Another seqnet
  command's output (results, a dataset or training run made elsewhere) is refused with a hint, unless
  ``overwrite``; a file seqnet did not write is refused even then. Dead temporary files (named with
  seqnet's mark) beside and inside those outputs are removed first: debris of a killed seqnet run.
* :func:`write_outputs`: the new outputs are written into a temporary sibling and swapped in with the
  user's other files (:func:`seqnet.security.folders.update_folder`); a kill leaves the old set whole
  or the new one whole. An error inside the temporary folder names the user's path.
* :func:`scratch`, :func:`private_temp`: working folders (timing maps, a demo without ``--out``) that a
  killed run leaves are removed by the next run.
"""

from __future__ import annotations

import contextlib
import logging
import os
import secrets
import shutil
import stat
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

from ..core.errors import OutputError, SeqnetError
from ..core.log import logger
from ..data.io import is_dataset_file
from ..security.digests import changed_files, file_digest
from ..security.dirs import remove_dead_temps
from ..security.files import TEMP_MARK, TEMP_SUFFIX, in_place_of, temp_prefix, write_json_atomic
from ..security.folders import update_folder
from ..security.jsonfile import read_json
from ..security.locks import locked
from ..security.ownership import MANIFEST, foreign_files, read_manifest
from ..security.text import shown
from ..train.run import is_run_file

RECORD = ".seqnet-outputs.json"  # which command wrote each output of the folder, and its files' digests
MAX_RECORD = 16 << 20


def is_marked_temp(name: str) -> bool:
    """Whether ``name`` is a temporary file or folder seqnet makes (``.<name>.seqnet-XXXX.tmp``)."""
    return name.startswith(".") and TEMP_MARK in name and name.endswith(TEMP_SUFFIX)


def read_record(root: Path) -> dict[str, dict[str, Any]]:
    """``{output name: {"kind", "files"}}`` of the folder's record (empty when it has none or it is unreadable)."""
    try:
        data = read_json(root / RECORD, "output record", OutputError, limit=MAX_RECORD)
    except (OSError, SeqnetError):
        return {}
    entries = data.get("entries") if isinstance(data, dict) else None
    if not isinstance(entries, dict):
        return {}
    return {k: v for k, v in entries.items() if isinstance(k, str) and isinstance(v, dict)
            and isinstance(v.get("kind"), str) and isinstance(v.get("files"), dict)}


def files_of(root: Path, name: str) -> list[str]:
    """The files of output ``name`` (itself, or every file under it), relative to ``root``."""
    top = root / name
    if top.is_symlink() or not top.is_dir():
        return [name] if top.exists() or top.is_symlink() else []
    return sorted(str(p.relative_to(root)) for p in top.rglob("*") if p.is_symlink() or not p.is_dir())


def written_by(root: Path, name: str, legacy: Iterable[str] = ()) -> str | None:
    """The command that wrote output ``name`` of ``root`` as it is now (its files and their digests as the
    record says), else None; an output without a record entry listed by a manifest of a ``legacy`` kind (what
    an older seqnet wrote, before the record) counts as that kind's."""
    rec = read_record(root).get(name)
    if rec is None:
        manifest = read_manifest(root) or {}
        listed = {f for f in manifest.get("files", ()) if isinstance(f, str)}
        old = manifest.get("kind") in set(legacy) and set(files_of(root, name)) <= listed
        return str(manifest["kind"]) if old else None
    if set(files_of(root, name)) != set(rec["files"]):
        return None
    try:
        return None if changed_files(root, rec["files"], error=OutputError) else rec["kind"]
    except SeqnetError:
        return None


def remove_debris(root: Path, names: Iterable[str]) -> None:
    """Remove the temporary files killed seqnet runs left beside the outputs ``names`` of ``root`` and inside
    them (names with seqnet's mark only; under each output folder's lock, so no live writer owns them)."""
    names = list(names)
    remove_dead_temps([root / n for n in names])
    for name in names:
        top = root / name
        if top.is_symlink() or not top.is_dir():
            continue
        with locked(top):
            for d in [top, *(p for p in top.rglob("*") if p.is_dir() and not p.is_symlink())]:
                for entry in os.scandir(d):
                    if is_marked_temp(entry.name) and entry.is_file(follow_symlinks=False):
                        logger.debug("removing %s, left by a run that ended", shown(entry.path))
                        os.unlink(entry.path)


def foreign_file(root: Path, name: str) -> str | None:
    """The first file of output ``name`` of ``root`` (relative to ``root``) that seqnet did not write, else None:
    a file is seqnet's when ``root``'s manifest lists it or, inside a folder, the folder's own manifest does (a
    dataset, a results folder) or it is a file a training run writes."""
    manifest = read_manifest(root) or {}
    listed = {f for f in manifest.get("files", ()) if isinstance(f, str)}
    rest = [f for f in files_of(root, name) if f not in listed]
    top = root / name
    if not rest or top.is_symlink() or not top.is_dir():
        return rest[0] if rest else None
    inner = foreign_files(top, lambda rel: is_dataset_file(rel) or is_run_file(rel))
    return f"{name}/{inner[0]}" if inner else None


def check_outputs_of(root: str | os.PathLike[str], names: Iterable[str], kind: str, what: str,
                     overwrite: bool = False, legacy: Iterable[str] = ()) -> None:
    """Refuse, before any work, to write the outputs ``names`` of ``seqnet {kind}`` into ``root`` where one is
    there that this command did not write (module docstring); ``overwrite`` lets it replace another seqnet
    command's output, never a file seqnet did not write. Call under ``root``'s lock."""
    root, names, legacy = Path(root), list(names), tuple(legacy)
    if root.exists() and not root.is_dir():
        raise OutputError(f"{shown(root)} exists and is not a folder; choose another output folder for the {what}")
    if not root.is_dir():
        return
    remove_debris(root, names)
    for name in [*names, RECORD]:
        path = root / name
        there = path.exists() or path.is_symlink()
        if not there or (name != RECORD and written_by(root, name, legacy) in (kind, *legacy)):
            continue
        foreign = foreign_file(root, name)
        if foreign is not None:
            raise OutputError(f"{shown(root / foreign)} was not written by seqnet; refusing to replace {shown(path)} "
                              f"with the {what} (move it away, or choose another output folder)")
        if not overwrite and name != RECORD:
            by = written_by(root, name, legacy)
            who = f"`seqnet {by}`" if by else "another seqnet command (or changed since)"
            raise OutputError(f"{shown(path)} was written by {who}, not by `seqnet {kind}`; refusing to replace "
                              f"it with the {what} (move it away, choose another output folder, or pass --overwrite)")


def write_outputs(root: str | os.PathLike[str], kind: str, what: str, write: Callable[[Path], Any],
                  overwrite: bool = False, legacy: Iterable[str] = ()) -> Path:
    """Write the outputs of ``seqnet {kind}`` into ``root`` as one new version: ``write(tmp)`` writes them into
    a temporary sibling (everything it leaves there is an output), the record says this command wrote them, and
    the folder is swapped in with the user's other files kept. Call under ``root``'s lock, after
    :func:`check_outputs_of` (checked again just before the swap)."""
    user = Path(root)

    def fill(tmp: Path) -> list[Path]:
        with user_paths(tmp, user):
            write(tmp)
        names = sorted(p.name for p in tmp.iterdir() if p.name not in (MANIFEST, RECORD))
        check_outputs_of(user, names, kind, what, overwrite, legacy)  # nothing foreign appeared meanwhile
        entries = {k: v for k, v in read_record(user).items() if k not in names and (user / k).exists()}
        for name in names:
            entries[name] = {"kind": kind, "files": {f: file_digest(tmp / f) for f in files_of(tmp, name)}}
        write_json_atomic(tmp / RECORD, {"entries": entries})
        return [p for p in tmp.rglob("*") if (p.is_symlink() or not p.is_dir()) and p.name != MANIFEST]

    return update_folder(user, fill, what, overwrite=True)  # what it replaces is seqnet's: checked above


@contextlib.contextmanager
def user_paths(tmp: Path, root: Path) -> Iterator[None]:
    """Errors raised and messages logged inside the block name ``root`` where they named the temporary folder
    ``tmp``."""

    def rename(record: logging.LogRecord) -> bool:
        text = record.getMessage()
        if str(tmp) in text:
            record.msg, record.args = text.replace(str(tmp), str(root)), ()
        return True

    logger.addFilter(rename)
    try:
        yield
    except OSError as e:
        raise in_place_of(e, tmp, root) from e
    except SeqnetError as e:
        e.args = tuple(a.replace(str(tmp), str(root)) if isinstance(a, str) else a for a in e.args)
        raise
    finally:
        logger.removeFilter(rename)


@contextlib.contextmanager
def scratch(root: str | os.PathLike[str]) -> Iterator[Path]:
    """A working folder beside ``root`` carrying seqnet's mark, removed afterwards; one a killed run left is
    removed by the next writer of ``root`` (:func:`seqnet.security.dirs.recover_dir`, under its lock)."""
    root = Path(root).absolute()
    root.parent.mkdir(parents=True, exist_ok=True)
    path = Path(tempfile.mkdtemp(dir=root.parent, prefix=temp_prefix(root.name), suffix=TEMP_SUFFIX))
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)


@contextlib.contextmanager
def private_temp(prefix: str) -> Iterator[Path]:
    """A folder ``<tmp>/<prefix>…`` for a run without an output folder, held under its lock and removed
    afterwards; the folders of killed runs (this user's, their lock free) are removed first."""
    base = Path(tempfile.gettempdir())
    remove_dead_private(base, prefix)
    path = base / f"{prefix}{os.getpid()}-{secrets.token_hex(4)}"
    with locked(path):
        path.mkdir(mode=0o700)
        try:
            yield path
        finally:
            shutil.rmtree(path, ignore_errors=True)


def remove_dead_private(base: Path, prefix: str) -> None:
    """Remove the :func:`private_temp` folders of ``base`` that killed runs left (a live run holds its lock)."""
    try:
        names = [n for n in os.listdir(base) if n.startswith(prefix) or (n.startswith(f".{prefix}")
                                                                         and n.endswith(".lock"))]
    except OSError:
        return
    for name in names:
        path = base / (name[1:-5] if name.endswith(".lock") and name.startswith(".") else name)
        try:
            st = os.lstat(base / name)
            if not (stat.S_ISDIR(st.st_mode) or name.endswith(".lock")) or st.st_uid != os.getuid() or \
                    (name.endswith(".lock") and (path.exists() or path.is_symlink())):
                continue
            with locked(path):  # a lock file without its folder: taken and removed on release
                if path.is_dir() and not path.is_symlink():
                    logger.debug("removing %s, left by a run that ended", shown(path))
                    shutil.rmtree(path)
        except (OSError, SeqnetError):  # a live run's (locked), or not ours to remove
            continue
