"""Writing files: atomic writes, the temporary files' mark, and OS failures as one-line errors.

Writes go to a temporary file beside the target (``.<name>.seqnet-XXXXXXXX.tmp``, created with
``O_EXCL | O_NOFOLLOW``: a planted link is never followed) and are renamed onto it only on success, so
a crash never leaves a half-written output; only files carrying that mark are ever removed as a dead
run's leftovers (:func:`seqnet.security.dirs.remove_dead_temps`). A failure names the user's path,
not the temporary file; a write cut short by a full disk or a file size limit, whatever the library
said (numpy's "N requested and M written", torch's "inline_container"), is one line, exit 1. Locks and
ownership of output directories: :mod:`seqnet.security.ownership`.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ConfigError, OutputError, ResourceError, SeqnetError
from ..core.npy import write_npy


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
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=temp_prefix(path.name), suffix=TEMP_SUFFIX)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, 0o666 & ~current_umask())  # mkstemp makes it 0600; a plain open() would not
        os.replace(tmp_path, path)
    except (OSError, RuntimeError) as e:
        if short_write(e):
            raise ResourceError(f"{path}: disk full while writing it (or a file size limit, ulimit -f); hint: check "
                                "the free space, or write the output elsewhere") from e
        if isinstance(e, OSError) and (e.filename in (str(tmp_path), tmp_path) or e.filename is None):
            raise type(e)(e.errno, e.strerror or str(e), str(path)) from e  # name the user's file, not ours
        raise
    finally:
        with contextlib.suppress(OSError):
            tmp_path.unlink()


TEMP_MARK, TEMP_SUFFIX = ".seqnet-", ".tmp"
_SHORT_WRITE = re.compile(r"\d+ requested and \d+ written|inline_container|PytorchStreamWriter failed|"
                          r"file write failed|No space left", re.IGNORECASE)


def temp_prefix(name: str) -> str:
    """The start of the name of a temporary file or folder seqnet makes beside ``name``: its mark."""
    return f".{name}{TEMP_MARK}"


def short_write(e: BaseException) -> bool:
    """Whether ``e`` is a write cut short by a full disk or a file size limit that the library reported without
    an errno (an ``OSError`` with one is named by :func:`os_error`)."""
    return isinstance(e, (OSError, RuntimeError)) and getattr(e, "errno", None) is None and \
        bool(_SHORT_WRITE.search(str(e)))


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
            write_npy(f, array)
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
    reason = _REASONS.get(e.errno or -1) or (e.strerror or " ".join(str(e).split())[:200] or type(e).__name__)
    if e.errno == errno.EISDIR and e.strerror and e.strerror != "Is a directory":
        reason = e.strerror
    path = f"{e.filename}: " if e.filename else ""
    other = f" -> {e.filename2}" if getattr(e, "filename2", None) else ""
    cls = ResourceError if e.errno in ENVIRONMENT_ERRNOS else OutputError
    return cls(f"{path}{reason}{other}")


def in_place_of(e: OSError, tmp: Path, final: Path) -> OSError:
    """``e`` naming the user's output ``final`` (and the file in it) instead of the temporary directory
    ``tmp`` it was being written in."""
    if e.filename:
        with contextlib.suppress(ValueError):
            e.filename = str(final / Path(e.filename).relative_to(tmp))
    return e
