"""File I/O shared by every stage: atomic writes, the one safe loader of torch files, and OS errors.

Writes go to a temporary file beside the target and are renamed onto it only on success, so a
crash never leaves a half-written output; an OS failure names the user's path, not the temporary
file. Torch files are read with ``weights_only=True``: they may hold tensors and plain data, never
code. Locks and ownership of output directories: :mod:`seqnet.core.ownership`.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from .errors import CheckpointError, ConfigError, OutputError, ResourceError, SeqnetError


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it onto ``path`` only on success.

    A crash inside the block leaves no half-written ``path`` behind.
    """
    path = Path(path)
    if not path.name:
        raise IsADirectoryError(errno.EISDIR, "an output file needs a name", str(path))
    if path.is_dir():
        raise IsADirectoryError(errno.EISDIR, "Is a directory (an output file was expected)", str(path))
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, 0o666 & ~current_umask())  # mkstemp makes it 0600; a plain open() would not
        os.replace(tmp_path, path)
    except OSError as e:
        if e.filename in (str(tmp_path), tmp_path) or e.filename is None:  # name the user's file, not ours
            raise type(e)(e.errno, e.strerror or str(e), str(path)) from e
        raise
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def current_umask() -> int:
    """The process umask (read without changing it for longer than an instant)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_text_atomic(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def write_json_atomic(path: str | os.PathLike[str], obj: Any) -> Path:
    """Write ``obj`` as indented, strictly valid JSON to ``path`` atomically (NaN or inf is an error)."""
    try:
        text = json.dumps(obj, indent=2, sort_keys=False, default=_json_default, allow_nan=False)
    except ValueError as e:
        raise ConfigError(f"refusing to write {path}: the results hold NaN or inf, which is not valid JSON ({e}); "
                          "this is a bug or an input without any valid query") from e
    return write_text_atomic(path, text + "\n")


def save_npy_atomic(path: str | os.PathLike[str], array: np.ndarray) -> Path:
    """Save ``array`` as ``.npy`` atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.save(f, array)
    return Path(path)


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return float(obj)
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"Object of type {type(obj).__name__} is not JSON serialisable")


def _numpy_globals() -> list[Any]:
    """numpy objects allowed in torch files (the original SeqNet code stored numpy scalars)."""
    core = np._core if hasattr(np, "_core") else np.core  # type: ignore[attr-defined]
    out: list[Any] = [np.dtype, *(type(np.dtype(t)) for t in (np.float64, np.float32, np.int64, np.int32, np.bool_))]
    for name in ("scalar", "_reconstruct"):
        fn = getattr(core.multiarray, name)
        out += [fn, (fn, f"numpy.core.multiarray.{name}"), (fn, f"numpy._core.multiarray.{name}")]
    return out + [np.ndarray]


def load_torch_file(path: str | os.PathLike[str], what: str = "checkpoint") -> Any:
    """Read a ``torch.save`` file safely (``weights_only``); :class:`CheckpointError` if missing or unreadable."""
    import torch

    path = Path(path)
    if not path.is_file():
        hint = " (it is a directory)" if path.is_dir() else ""
        raise CheckpointError(f"{what} not found: {path}{hint}")
    try:
        with torch.serialization.safe_globals(_numpy_globals()):
            return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises RuntimeError, UnpicklingError, EOFError, zipfile errors ...
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise CheckpointError(f"cannot read {what} {path}: corrupted or not a torch file ({first[:200]})") from e


# errno values that mean the environment failed (exit 1), not the input (exit 2)
ENVIRONMENT_ERRNOS = frozenset({errno.ENOSPC, errno.EROFS, errno.EDQUOT, errno.EACCES, errno.EPERM, errno.EIO,
                                errno.EMFILE, errno.ENFILE, errno.ENOMEM, errno.EBUSY, errno.ETXTBSY, errno.EPIPE,
                                errno.EFBIG})
_REASONS = {errno.ENOSPC: "no space left on device", errno.EROFS: "read-only file system",
            errno.EDQUOT: "disk quota exceeded", errno.EACCES: "permission denied",
            errno.EPERM: "operation not permitted", errno.EEXIST: "a file is in the way",
            errno.ENOTDIR: "a path component is a file, not a directory",
            errno.EISDIR: "is a directory", errno.ENOENT: "no such file or directory",
            errno.EPIPE: "broken pipe (the reader of the output went away)",
            errno.EFBIG: "file too large (a file size limit, e.g. ulimit -f, or the file system's)"}


def os_error(e: OSError) -> SeqnetError:
    """One user-facing error for an OS failure: the path and the reason; :class:`ResourceError`
    (exit 1) for a failing environment (disk full, read-only, permission), else :class:`OutputError`."""
    reason = _REASONS.get(e.errno or -1) or (e.strerror or type(e).__name__).lower()
    if e.errno == errno.EISDIR and e.strerror and e.strerror != "Is a directory":
        reason = e.strerror
    path = f"{e.filename}: " if e.filename else ""
    other = f" -> {e.filename2}" if getattr(e, "filename2", None) else ""
    cls = ResourceError if e.errno in ENVIRONMENT_ERRNOS else OutputError
    return cls(f"{path}{reason}{other}")


SAMPLE_BLOCK = 4096
SAMPLE_BLOCKS = 16


def file_digest(path: str | os.PathLike[str], full: bool = False) -> dict[str, Any]:
    """``{"size", "sample"}`` of a file: its size and a BLAKE2b hash of its first and last 64 KiB and of
    16 evenly spaced 4 KiB blocks (cheap on a file of any size); with ``full`` also ``"full"``, the hash of
    every byte."""
    import hashlib

    size, sample = os.path.getsize(path), hashlib.blake2b(digest_size=16)
    with open(path, "rb") as f:
        offsets = [0, max(0, size - 65536), *(int(size * (i + 0.5) / SAMPLE_BLOCKS) for i in range(SAMPLE_BLOCKS))]
        for off, n in zip(offsets, [65536, 65536, *[SAMPLE_BLOCK] * SAMPLE_BLOCKS], strict=True):
            f.seek(off)
            sample.update(f.read(n))
        out = {"size": size, "sample": sample.hexdigest()}
        if full:
            whole = hashlib.blake2b(digest_size=16)
            f.seek(0)
            for chunk in iter(lambda: f.read(1 << 20), b""):
                whole.update(chunk)
            out["full"] = whole.hexdigest()
    return out


def changed_files(root: Path, digests: dict[str, Any], full: bool = False) -> list[str]:
    """The files of ``digests`` that are missing or differ from what :func:`file_digest` recorded."""
    changed = []
    for rel, want in (digests or {}).items():
        f = root / rel
        deep = full and "full" in want
        got = file_digest(f, deep) if f.is_file() else {}
        if got.get("size") != want.get("size") or got.get("sample") != want.get("sample") or (
                deep and got["full"] != want["full"]):
            changed.append(rel)
    return changed


def verify_digests(root: Path, digests: dict[str, Any], error: type[SeqnetError], what: str, hint: str,
                   full: bool = False) -> None:
    """Every file of ``digests`` (as :func:`file_digest` recorded them when ``root`` was written) is there
    with the same size and sampled hash (``full``: and the same bytes); ``error`` naming the first that is not
    (:func:`changed_files`)."""
    changed = changed_files(root, digests, full)
    if changed:
        f = root / changed[0]
        if not f.is_file():
            raise error(f"{f} is missing from the {what} (hint: {hint})")
        raise error(f"{f} changed since the {what} was written ({f.stat().st_size} bytes, "
                    f"{digests[changed[0]].get('size')} then, or other contents); hint: {hint}")


SPACE_MARGIN = 16 * 2**20


def check_space(folder: Path, needed: int, what: str, largest: int | None = None) -> None:
    """Refuse to start writing ``needed`` bytes into ``folder`` (one line, exit 1) when the file system
    has less free, or one file of ``largest`` bytes (default: half) when the process's file size limit
    (``ulimit -f``) is lower: a library that hits either mid-write may not fail cleanly (HDF5, memory maps)."""
    import resource
    import shutil

    limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    largest = needed // 2 if largest is None else largest
    if limit != resource.RLIM_INFINITY and largest > limit:
        raise ResourceError(f"{folder}: {what} make a file of about {largest / 2**20:.0f} MiB, over this process's "
                            f"file size limit of {limit / 2**20:.0f} MiB (ulimit -f); hint: raise the limit")
    try:
        free = shutil.disk_usage(folder).free
    except OSError:
        return
    if free < needed + SPACE_MARGIN:
        raise ResourceError(f"{folder}: {what} need about {(needed + SPACE_MARGIN) / 2**20:.0f} MiB, only "
                            f"{free / 2**20:.0f} MiB free; hint: free some space or write the output elsewhere")


def in_place_of(e: OSError, tmp: Path, final: Path) -> OSError:
    """``e`` naming the user's output ``final`` (and the file in it) instead of the temporary directory
    ``tmp`` it was being written in."""
    if e.filename:
        with contextlib.suppress(ValueError):
            e.filename = str(final / Path(e.filename).relative_to(tmp))
    return e


def special_file(path: str | os.PathLike[str]) -> str | None:
    """``"FIFO"``, ``"socket"``, ``"character device"`` or ``"block device"`` when ``path`` is one (checked
    with ``stat``, never opened), else None (a regular file, a directory, or nothing there)."""
    import stat

    try:
        mode = os.stat(path).st_mode
    except OSError:
        return None
    for test, kind in ((stat.S_ISFIFO, "FIFO"), (stat.S_ISSOCK, "socket"), (stat.S_ISCHR, "character device"),
                       (stat.S_ISBLK, "block device")):
        if test(mode):
            return kind
    return None


class Written(os.PathLike):
    """What a stage returns: the main file it wrote (``path``; the object is path-like) and what it wrote
    there (``data``), so a caller — the CLI — prints the result without reading the file back."""

    def __init__(self, path: str | Path, data: Any) -> None:
        self.path, self.data = Path(path), data

    def __fspath__(self) -> str:
        return str(self.path)

    def __getattr__(self, name: str) -> Any:  # the Path API (read_text, parent, suffix, ...) of ``path``
        if name in ("path", "data"):
            raise AttributeError(name)
        return getattr(self.path, name)

    def __str__(self) -> str:
        return str(self.path)

    def __repr__(self) -> str:
        return f"Written({str(self.path)!r})"

    def __eq__(self, other: object) -> bool:
        return self.path == (other.path if isinstance(other, Written) else other)

    def __hash__(self) -> int:
        return hash(self.path)
