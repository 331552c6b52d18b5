"""Opening an input file, and paths or names read from one: nothing hangs, nothing leaves its folder.

* :func:`open_input` opens a file without blocking (a FIFO, a socket or a device never hangs the
  process) and refuses anything that is not a regular file, before a byte is read.
* :func:`read_bytes` reads a whole small file (JSON, text), refusing one larger than its bound.
* :func:`inside` resolves a path read from a file (``dataset.json``'s traverses, ``map.json``'s models,
  checksum keys) inside that file's folder: absolute paths, ``..`` and links leading out are refused.
* :func:`within` says whether a resolved path lies in a resolved folder (the one test of the module's guards).
* :func:`find_inside` finds the file a name kept as a user gave it (``../data/img.png``, an absolute path)
  names inside a given folder: by the name, its path, or its last parts, each through :func:`inside`.
* :func:`check_name` refuses a name (an image name, a key) holding a NUL or a line separator.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import stat
from pathlib import Path
from typing import BinaryIO

from ..core.errors import DatasetError, SeqnetError

ErrorType = type[SeqnetError]
_KINDS = ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISDIR, "a directory"))


def kind_of(mode: int) -> str:
    """What a ``stat`` mode says a path is, in words (``"a regular file"`` for one)."""
    return next((kind for test, kind in _KINDS if test(mode)), "a regular file" if stat.S_ISREG(mode) else
                "not a regular file")


def special_file(path: str | os.PathLike[str]) -> str | None:
    """``"FIFO"``, ``"socket"``, ``"character device"`` or ``"block device"`` when ``path`` is one (checked
    with ``stat``, never opened), else None (a regular file, a directory, or nothing there)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return None
    for test, kind in ((stat.S_ISFIFO, "FIFO"), (stat.S_ISSOCK, "socket"), (stat.S_ISCHR, "character device"),
                       (stat.S_ISBLK, "block device")):
        if test(mode):
            return kind
    return None


def open_input(path: str | os.PathLike[str], what: str = "file", error: ErrorType = DatasetError,
               follow: bool = True) -> BinaryIO:
    """``path`` opened for reading as a binary file object, never blocking: a FIFO, socket, device or
    directory is refused (``error``) before a byte is read (``--query <(...)``: a pipe cannot be read
    twice, so it is refused with the hint to save it to a file). ``follow=False`` refuses a symbolic link."""
    flags = os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | (0 if follow else os.O_NOFOLLOW)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError as e:
        raise error(f"{what} not found: {path}") from e
    except IsADirectoryError as e:
        raise error(f"{what} {path} is a directory, not a file") from e
    except OSError as e:
        if e.errno == errno.ELOOP and not follow:
            raise error(f"{what} {path} is a symbolic link; seqnet does not follow links here") from e
        raise
    mode = os.fstat(fd).st_mode
    if not stat.S_ISREG(mode):
        os.close(fd)
        hint = " (a pipe or process substitution is read once only: save it to a file first)" \
            if stat.S_ISFIFO(mode) else ""
        raise error(f"{what} {path} is {kind_of(mode)}, not a regular file{hint}")
    fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~os.O_NONBLOCK)
    return os.fdopen(fd, "rb")


def read_bytes(path: str | os.PathLike[str], limit: int, what: str = "file", error: ErrorType = DatasetError) -> bytes:
    """The bytes of a regular file of at most ``limit`` bytes (:func:`open_input`); a larger one is refused
    before it is read. Read at its size (``f.read(limit)`` set ``limit`` bytes of address space aside, 1 GiB for a
    100-byte ``names.txt``: under ``ulimit -v`` a dataset's load died of it)."""
    with open_input(path, what, error) as f:
        size = os.fstat(f.fileno()).st_size
        if size > limit:
            raise error(f"{what} {path} has {size} bytes, more than the {limit} such a file may have")
        data = f.read(size + 1)  # its size, not the limit: read(n) sets n bytes of address space aside
        if len(data) > size:  # it grew since: read on, up to the limit
            data += f.read(limit + 1 - len(data))
    if len(data) > limit:
        raise error(f"{what} {path} grew past {limit} bytes while it was read")
    return data


def read_text(path: str | os.PathLike[str], limit: int = 1 << 30, what: str = "file",
              error: ErrorType = DatasetError) -> str:
    """A UTF-8 text file of at most ``limit`` bytes; ``error`` naming the byte where it is not UTF-8."""
    try:
        return read_bytes(path, limit, what, error).decode("utf-8")
    except UnicodeDecodeError as e:
        raise error(f"{path}: not UTF-8 text ({e.reason} at byte {e.start})") from e


def inside(root: str | os.PathLike[str], rel: object, what: str, error: ErrorType = DatasetError) -> Path:
    """``root / rel`` for a relative path ``rel`` read from a file in ``root``: refused (``error``) when it
    is not a non-empty string, is absolute, holds ``..``, a NUL or a backslash, or leads (through
    symbolic links) outside ``root``."""
    if not isinstance(rel, str) or not rel.strip() or "\x00" in rel or "\\" in rel:
        raise error(f"{what}: {rel!r} is not a relative path inside {root}")
    parts = Path(rel).parts
    if Path(rel).is_absolute() or ".." in parts or not parts:
        raise error(f"{what}: {rel!r} leads outside {root} (paths read from a file must stay in its folder)")
    out = Path(root) / rel
    real_root = os.path.realpath(root)
    real = os.path.realpath(out)
    if not within(real_root, real):
        raise error(f"{what}: {rel!r} leads outside {root} through a symbolic link (to {real})")
    return out


def within(real_root: str, real: str) -> bool:
    """Whether the resolved path ``real`` is the resolved folder ``real_root`` or lies in it (both through
    :func:`os.path.realpath`)."""
    return os.path.commonpath([real_root, real]) == real_root


def find_inside(root: str | os.PathLike[str], name: object, what: str, error: ErrorType = DatasetError) -> Path:
    """The existing file inside the folder ``root`` that ``name`` (read from a file: untrusted) names, for names
    kept as a user gave them (``../data/winter/img.png``, ``/data/winter/img.png``, ``img.png``). Looked for, in
    order: ``root / name`` (a relative name without ``..``); the path ``name`` itself (absolute, or relative to
    the working directory) when it resolves inside ``root``; the name's trailing parts (``winter/img.png``, then
    ``img.png``) in ``root``, unless the path ``name`` is an existing file outside ``root`` (a file of the same
    name in ``root`` would be another picture). Each is checked by :func:`inside` (no ``..``, no symbolic link out
    of ``root``), so nothing outside ``root`` is ever returned; ``error`` naming ``root`` and what was looked for
    when none exists."""
    if not isinstance(name, str) or not name.strip() or "\x00" in name or "\\" in name:
        raise error(f"{what}: {name!r} is not a path to look for in {root}")
    real_root = os.path.realpath(root)
    tried, linked = [], []
    for rel in _names_to_try(name, real_root):
        try:
            path = inside(root, rel, what, error)
        except SeqnetError:
            linked.append(rel)
            continue
        if os.path.exists(path) and not os.path.isdir(path):  # a FIFO is returned: opening it says what it is
            return path
        tried.append(rel)
    why = [f"looked for {', '.join(map(repr, tried))} there"] if tried else []
    if linked:
        why.append(f"{', '.join(map(repr, linked))} there leads outside {root} through a symbolic link (not read)")
    as_given = os.path.realpath(name)
    if len(Path(name).parts) > 1 and not within(real_root, as_given):
        why.append(f"the path as given leads outside {root}, to the file {as_given}: not read, nor any file of its "
                   "name in the folder (hint: name the folder that holds it)" if os.path.exists(as_given) else
                   f"the path as given leads outside {root}, to {as_given}, where there is no file")
    raise error(f"{what} {name!r}: not found in {root} ({'; '.join(why) or 'nothing to look for'})")


def _names_to_try(name: str, real_root: str) -> list[str]:
    """The paths relative to ``root`` that :func:`find_inside` tries for ``name``, in order, each once."""
    parts = Path(name).parts
    out = [name] if not Path(name).is_absolute() and ".." not in parts else []
    if len(parts) > 1:
        real = os.path.realpath(name)
        if real != real_root and within(real_root, real):
            out.append(os.path.relpath(real, real_root))
        elif os.path.exists(real):  # the file is elsewhere: one of the same name in root is another picture
            return list(dict.fromkeys(out))
        out += [str(Path(*parts[i:])) for i in range(1, len(parts)) if ".." not in parts[i:]]
    return list(dict.fromkeys(out))

def check_name(name: str, where: str, error: ErrorType = DatasetError) -> str:
    """``name`` unless it holds a NUL (no file system or CSV keeps one); ``error`` naming it."""
    if "\x00" in name:
        raise error(f"{where}: name {name!r} contains a NUL character")
    return name


def nofollow_fd(path: str | os.PathLike[str], flags: int, mode: int = 0o644, what: str = "file",
                error: ErrorType = DatasetError) -> int:
    """``os.open(path, flags | O_NOFOLLOW | O_CLOEXEC)`` for a file seqnet creates or takes over (a lock, a
    temporary file): a symbolic link planted there is refused, never followed to truncate its target."""
    try:
        fd = os.open(path, flags | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK, mode)
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise error(f"{what} {path} is a symbolic link, which seqnet does not follow when it creates a file; "
                        "remove the link") from e
        raise
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        with contextlib.suppress(OSError):
            os.close(fd)
        raise error(f"{what} {path} exists and is not a regular file; remove it")
    fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~os.O_NONBLOCK)
    return fd
