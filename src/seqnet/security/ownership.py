"""What seqnet wrote, so that it replaces or deletes only that (locks: :mod:`seqnet.security.locks`).

* A *manifest* (``.seqnet-manifest.json`` inside an output directory) lists the files a seqnet run
  wrote there. :func:`remove_owned_dir` deletes a directory only when every file in it is listed
  (or, for directories older than manifests, matches what seqnet writes): a user's file is never lost.
"""

from __future__ import annotations

import datetime
import os
import shutil
from collections.abc import Callable, Iterable
from pathlib import Path

from .._version import __version__
from ..core.errors import OutputError, SeqnetError
from .digests import file_digest
from .files import write_json_atomic
from .jsonfile import read_json

MANIFEST = ".seqnet-manifest.json"


def now() -> str:
    """The local time to the second, as manifests and lock files record it."""
    return datetime.datetime.now().isoformat(timespec="seconds")


def write_manifest(root: str | os.PathLike[str], kind: str, files: Iterable[str | os.PathLike[str]],
                   digests: bool = True) -> Path:
    """Record in ``root/.seqnet-manifest.json`` that this seqnet ``kind`` of run wrote ``files`` (under ``root``),
    with their sizes and sampled hashes (``digests``; off for files a run keeps rewriting, a training run's):
    a file a user later saved under one of those names is then not taken for seqnet's (:func:`owned`)."""
    root = Path(root)
    rel = sorted({str(Path(f).absolute().relative_to(root.absolute())) for f in files})
    record = {"kind": kind, "seqnet_version": __version__, "written": now(), "files": rel}
    if digests:
        record["digests"] = {r: file_digest(root / r) for r in rel if (root / r).is_file()}
    return write_json_atomic(root / MANIFEST, record)


def owned(root: Path, manifest: dict | None = None) -> set[str]:
    """The files of ``root`` its manifest says seqnet wrote and that are still as it wrote them (same size and
    sampled hash, where the manifest recorded them)."""
    manifest = read_manifest(root) if manifest is None else manifest
    if not manifest:
        return set()
    digests = manifest.get("digests") if isinstance(manifest.get("digests"), dict) else {}
    out = set()
    for rel in manifest["files"]:
        if not isinstance(rel, str):
            continue
        want, f = digests.get(rel), root / rel
        if want is None or (f.is_file() and not f.is_symlink() and _same(f, want)):
            out.add(rel)
    return out


def _same(f: Path, want: object) -> bool:
    try:
        return file_digest(f) == want
    except (OSError, SeqnetError):
        return False


def read_manifest(root: Path) -> dict | None:
    """The manifest of ``root``, or None when it has none (or an unreadable one)."""
    try:
        data = read_json(root / MANIFEST, "manifest", OutputError, limit=256 << 20)
    except (OSError, OutputError):
        return None
    return data if isinstance(data, dict) and isinstance(data.get("files"), list) else None


def foreign_files(root: Path, known: Callable[[str], bool] | None = None) -> list[str]:
    """Files under ``root`` (relative paths) that seqnet did not write: not in its manifest, and
    (for a directory without a manifest) not accepted by ``known``."""
    manifest = read_manifest(root)
    listed = owned(root, manifest)
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
