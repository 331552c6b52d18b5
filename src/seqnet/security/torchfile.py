"""The one loader of torch files (checkpoints, fitted state): tensors and plain data, never code.

``torch.load(weights_only=True)`` already refuses code; three more things are needed for a stranger's file:

* **the archive first**: only torch's zip format (``torch.save`` since torch 1.6) is read, every member
  stored uncompressed and within the file's bytes, so no declared size allocates more than the file
  holds (the legacy format allocates each storage at its declared size before reading it: refused,
  with the way to re-save it);
* **no numpy state from the file**: the original SeqNet code stored numpy scalars, which pickle as
  ``numpy.dtype`` + ``dtype.__setstate__`` (a crafted state crashes the interpreter). Here those names
  resolve to seqnet's own constructors (:func:`_dtype`, :func:`_scalar`, :func:`_reconstruct`) that take
  plain numeric types only and build the value from its bytes;
* every failure is one :class:`~seqnet.core.errors.CheckpointError` naming the file.
"""

from __future__ import annotations

import os
import re
import zipfile
from typing import IO, Any

import numpy as np

from ..core.errors import CheckpointError
from .inputs import open_input

_CODE = re.compile(r"^(?:[biuf][1248]|b1|\?)$")


class _Dtype:
    """A numeric numpy dtype named in a pickle (``numpy.dtype(code, align, copy)``), built by seqnet."""

    def __init__(self, code: object) -> None:
        if not isinstance(code, str) or not _CODE.match(code):
            raise CheckpointError(f"refusing numpy dtype {code!r} in a torch file: plain numbers only")
        self.dtype = np.dtype(code)

    def __setstate__(self, state: object) -> None:
        if not isinstance(state, tuple) or len(state) < 5 or state[1] not in ("<", ">", "|", "=") or \
                any(x is not None for x in state[2:5]):
            raise CheckpointError("refusing a numpy dtype state with fields or sub-arrays in a torch file")
        if state[1] in "<>":
            self.dtype = self.dtype.newbyteorder(state[1])


class _Array:
    """A numpy array named in a pickle (``_reconstruct`` then its state), built from its bytes by seqnet."""

    array: np.ndarray | None = None

    def __setstate__(self, state: object) -> None:
        if not isinstance(state, tuple) or len(state) != 5 or not isinstance(state[2], _Dtype):
            raise CheckpointError("refusing a numpy array state in a torch file that is not plain numbers")
        _, shape, dt, fortran, raw = state
        raw = raw.encode("latin-1") if isinstance(raw, str) else raw
        if not isinstance(shape, tuple) or not all(isinstance(s, int) and s >= 0 for s in shape) or \
                not isinstance(raw, bytes) or len(raw) != int(np.prod(shape, dtype=object)) * dt.dtype.itemsize:
            raise CheckpointError("refusing a numpy array in a torch file whose bytes do not match its shape")
        self.array = np.frombuffer(raw, dt.dtype).reshape(shape, order="F" if fortran else "C").copy()


class _NdarrayType:
    """``numpy.ndarray`` as the argument of ``_reconstruct`` (nothing else)."""


def _dtype(code: object, align: object = False, copy: object = True) -> _Dtype:
    return _Dtype(code)


def _scalar(dt: object, data: object = None) -> Any:
    data = data.encode("latin-1") if isinstance(data, str) else data
    if not isinstance(dt, _Dtype) or not isinstance(data, bytes) or len(data) != dt.dtype.itemsize:
        raise CheckpointError("refusing a numpy scalar in a torch file that is not plain numbers")
    return np.frombuffer(data, dt.dtype)[0]


def _reconstruct(cls: object, shape: object = (0,), code: object = b"b") -> _Array:
    if cls is not _NdarrayType:
        raise CheckpointError("refusing numpy _reconstruct of anything but an ndarray in a torch file")
    return _Array()


def _safe_globals() -> list[Any]:
    """What a torch file may name beyond torch's own tensors and containers: seqnet's constructors."""
    out: list[Any] = [(_Dtype, "seqnet.security.torchfile._Dtype"), (_Array, "seqnet.security.torchfile._Array"),
                      (_NdarrayType, "numpy.ndarray"), (_dtype, "numpy.dtype")]
    for core in ("numpy.core.multiarray", "numpy._core.multiarray"):
        out += [(_scalar, f"{core}.scalar"), (_reconstruct, f"{core}._reconstruct")]
    return out


def check_archive(f: IO[bytes], where: str, what: str) -> None:
    """A torch zip archive whose members are all stored and within the file (see the module docstring)."""
    size = os.fstat(f.fileno()).st_size
    if f.read(4) != b"PK\x03\x04":
        raise CheckpointError(f"cannot read {what} {where}: not a torch file in the zip format of torch >= 1.6 "
                              "(the legacy format is not read: load and re-save it with torch.save in a trusted "
                              "environment)")
    f.seek(0)
    try:
        with zipfile.ZipFile(f) as z:
            infos = z.infolist()
    except Exception as e:  # noqa: BLE001 - zipfile raises BadZipFile, NotImplementedError, ValueError, OSError ...
        raise CheckpointError(f"cannot read {what} {where}: a damaged archive ({' '.join(str(e).split())[:160]})") \
            from e
    for info in infos:
        if info.compress_type != zipfile.ZIP_STORED or info.file_size != info.compress_size or \
                info.file_size > size:
            raise CheckpointError(f"cannot read {what} {where}: member {info.filename!r} declares {info.file_size} "
                                  "bytes it does not store as torch does (a damaged or crafted file)")


def load_torch_file(path: str | os.PathLike[str], what: str = "checkpoint", installed: bool = False,
                    mapped: bool = False) -> Any:
    """A ``torch.save`` file read safely (module docstring); :class:`CheckpointError` if missing or unreadable.
    ``installed``: a file shipped inside an installed package (trusted like its code: pretrained weights), which
    may be in torch's legacy format. ``mapped``: the tensors are mapped from the file, not read into memory (for
    a look at a checkpoint's architecture; the file opened here, through ``/proc/self/fd``, where the system has
    it; else read as usual)."""
    import torch

    with open_input(path, what, CheckpointError) as f:
        if not installed:
            check_archive(f, str(path), what)
        f.seek(0)
        fd_path = f"/proc/self/fd/{f.fileno()}"
        source: Any = fd_path if mapped and os.path.exists(fd_path) else f
        try:
            with torch.serialization.safe_globals(_safe_globals()):
                value = torch.load(source, map_location="cpu", weights_only=True, mmap=source is not f)
        except CheckpointError as e:
            raise CheckpointError(f"cannot read {what} {path}: {e}") from e
        except Exception as e:  # torch raises RuntimeError, UnpicklingError, EOFError, zipfile errors ...
            first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            raise CheckpointError(f"cannot read {what} {path}: corrupted or not a torch file ({first[:200]})") from e
    return _resolved(value, str(path))


def _check_tensor(t: Any, where: str) -> None:
    """A tensor may not declare more elements than its storage holds (zero or overlapping strides would make a
    1 KB file expand to gigabytes when the tensor is copied)."""
    if t.numel() * t.element_size() > t.untyped_storage().nbytes():
        raise CheckpointError(f"{where}: a tensor of shape {tuple(t.shape)} declares more elements than the file "
                              f"stores for it ({t.untyped_storage().nbytes()} bytes); a damaged or crafted file")


def _resolved(value: Any, where: str) -> Any:
    """``value`` with every numpy array built from the file (:class:`_Array`) in its place (dicts, lists, tuples;
    iteratively: no recursion limit to reach)."""
    if isinstance(value, _Array):
        return value.array
    if hasattr(value, "untyped_storage"):
        _check_tensor(value, where)
    root = [value]
    todo: list[Any] = [root]
    seen: set[int] = set()
    while todo:
        node = todo.pop()
        if id(node) in seen:
            continue
        seen.add(id(node))
        keys = node.keys() if isinstance(node, dict) else range(len(node)) if isinstance(node, list) else ()
        for k in list(keys):
            item = node[k]
            if type(item).__module__.startswith("torch") and hasattr(item, "untyped_storage"):
                _check_tensor(item, where)
            if isinstance(item, _Array):
                node[k] = item.array
            elif isinstance(item, tuple) and any(isinstance(x, _Array) for x in item):
                node[k] = tuple(x.array if isinstance(x, _Array) else x for x in item)
            elif isinstance(item, (dict, list)):
                todo.append(item)
            elif isinstance(item, tuple):
                todo.append(list(item))  # tensors inside a tuple are checked too
    return root[0]
