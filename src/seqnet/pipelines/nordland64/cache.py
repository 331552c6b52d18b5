"""The nordland64 cache (descriptors and models, reused by later runs and by the experiments): valid only whole.

A cache folder holds up to three *units*: the descriptor chosen on val (:data:`CHOICE`), the descriptors
(:data:`DESCRIPTORS`: ``dataset/``, ``flip_train.npy``) and the models (:data:`MODELS`: ``models/`` and the
training runs that made them). Its record (:data:`RECORD`) says

* which entries the cache made (``owned``): only those are ever replaced (unless ``overwrite``), so a
  user's own dataset or training run in their place is refused, never deleted;
* per unit, the key of the settings it was made with and the digest of every one of its files (and,
  for the models, of the descriptors they were trained on).

A unit is reused only when its key matches and every file is as recorded. Before a unit is rewritten
its key is removed from the record (and its entries claimed); its key is written last, after all its
files: a kill at any moment leaves a unit that is reused whole or rebuilt, never old and new files mixed.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from ...core.errors import OutputError, SeqnetError
from ...security.digests import changed_files, file_digest
from ...security.dirs import remove_dead_temps
from ...security.files import write_json_atomic
from ...security.jsonfile import read_json
from ...security.ownership import check_replaceable
from ...security.text import shown
from ...train.run import RUN_FILES, is_run_file

RECORD = ".seqnet-cache.json"
FORMAT = "seqnet nordland64 cache 1"
CHOICE = ("descriptor_choice.json",)  # the descriptor chosen on val (every candidate's score)
DESCRIPTORS = ("dataset", "flip_train.npy")
MODELS = ("models", "runs/seqnet", "runs/s1")
MAX_RECORD = 16 << 20


def read_record(root: Path) -> dict[str, Any] | None:
    """The record of the cache folder ``root`` (an empty one when there is none); None when a file of that
    name is there but is not a cache record (damaged, or not seqnet's)."""
    path = root / RECORD
    if not (path.exists() or path.is_symlink()):
        return {"format": FORMAT, "owned": [], "units": {}}
    try:
        data = read_json(path, "cache record", OutputError, limit=MAX_RECORD)
    except (OSError, SeqnetError):
        return None
    ok = isinstance(data, dict) and data.get("format") == FORMAT and isinstance(data.get("owned"), list) and \
        all(isinstance(e, str) for e in data["owned"]) and isinstance(data.get("units"), dict)
    return data if ok else None


def check_owned(root: str | os.PathLike[str], entries: Iterable[str], overwrite: bool = False) -> None:
    """Refuse (:class:`OutputError`, with a hint) to replace an entry of ``entries`` that is in ``root`` but
    was not made by this cache (its record does not claim it), unless ``overwrite``; and a training run
    folder holding a file a run does not write (never deleted, even with ``overwrite``). Dead temporary files
    in those run folders are removed (call under ``root``'s lock)."""
    root, entries = Path(root), list(entries)
    if not root.is_dir():
        return
    record = read_record(root)
    if record is None and not overwrite:
        raise OutputError(f"{shown(root / RECORD)} is not a seqnet cache record; refusing to use {shown(root)} as "
                          "a cache (move it away, choose another output or --cache folder, or pass --overwrite)")
    for entry in entries:
        path = root / entry
        if (path.exists() or path.is_symlink()) and not overwrite and entry not in (record or {})["owned"]:
            raise OutputError(f"{shown(path)} was not made by this cache (a dataset or run of your own, or the cache "
                              "of an older seqnet); refusing to replace it (move it away, choose another output or "
                              "--cache folder, or pass --overwrite)")
        if entry.startswith("runs/") and path.is_dir() and not path.is_symlink():
            remove_dead_temps([path / f for f in RUN_FILES])
            check_replaceable(path, "training run", is_run_file)


def unit(root: Path, name: str, key: str, inputs: Any = None) -> dict[str, Any] | None:
    """The record of unit ``name`` of ``root`` when it can be reused: made with ``key`` (and from ``inputs``,
    when given) and every file as it was written; else None."""
    record = read_record(root) or {"units": {}}
    u = record["units"].get(name)
    if not isinstance(u, dict) or u.get("key") != key or not isinstance(u.get("files"), dict) or not u["files"]:
        return None
    if inputs is not None and u.get("inputs") != inputs:
        return None
    try:
        return None if changed_files(root, u["files"], full=True, error=OutputError) else u
    except SeqnetError:
        return None


def unit_files(root: Path, name: str) -> dict[str, Any] | None:
    """The digests of the files of unit ``name`` of ``root`` as recorded (None when it has no such unit)."""
    u = (read_record(root) or {"units": {}})["units"].get(name)
    return u.get("files") if isinstance(u, dict) and isinstance(u.get("files"), dict) else None


def open_unit(root: Path, name: str, entries: Iterable[str], overwrite: bool = False) -> None:
    """Before unit ``name`` is (re)written: its entries checked (:func:`check_owned`) and claimed, its key
    removed (first: from now on the unit is rebuilt until :func:`seal`), dead temporary files removed."""
    entries = list(entries)
    check_owned(root, entries, overwrite)
    record = read_record(root) or {"format": FORMAT, "owned": [], "units": {}}
    record["units"].pop(name, None)
    record["owned"] = sorted({*record["owned"], *entries})
    remove_dead_temps([root / RECORD, *(root / e for e in entries)])
    write_json_atomic(root / RECORD, record)


def seal(root: Path, name: str, key: str, files: Iterable[str], **extra: Any) -> dict[str, Any]:
    """After every file of unit ``name`` is written: its key and the digests of ``files`` (relative to ``root``)
    recorded, last. Returns the unit's record."""
    record = read_record(root) or {"format": FORMAT, "owned": [], "units": {}}
    u = {"key": key, "files": {f: file_digest(root / f, full=True) for f in sorted(files)}, **extra}
    record["units"][name] = u
    write_json_atomic(root / RECORD, record)
    return u


def files_under(root: Path, entry: str) -> list[str]:
    """The files of ``entry`` (a file, or every file under a folder), relative to ``root``."""
    top = root / entry
    if top.is_file():
        return [entry]
    return sorted(str(p.relative_to(root)) for p in top.rglob("*") if p.is_file())
