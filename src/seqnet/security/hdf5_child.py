"""Reading an HDF5 file inside the sandbox's child (:mod:`seqnet.security.sandbox`); the parent side is
:mod:`seqnet.security.hdf5file`.

The file is opened from a file object (``h5py``'s ``fileobj`` driver: the library is given no name, so it
cannot resolve another file relative to it) after :func:`seqnet.security.inputs.open_input`. Refused
before any data is read: external links, external storage, virtual datasets; a dataset whose declared
shape × item size exceeds its bound (the file's size for contiguous or compact data, :data:`MAX_RATIO`
times it for chunked or compressed data, and the parent's memory bound). Numbers are streamed in slabs
of :data:`SLAB` bytes (the child never holds a whole dataset), strings are sent in the answer; other
datasets (compound, references, ...) are skipped and named.
"""

from __future__ import annotations

import math
import os
from typing import IO, Any

import numpy as np

from ..core.errors import DatasetError
from .arrays import MAX_RATIO
from .inputs import open_input
from .sandbox import answer

SLAB = 32 << 20
MAX_ATTR = 16 << 20


def dump(request: dict[str, Any], out: IO[bytes]) -> None:
    """Answer the file's root attributes (``mode`` ``attrs``), or also its datasets: numbers announced and
    streamed (``data``), or only read through (``check``: every byte decoded, nothing sent)."""
    import h5py

    path, mode, limit = str(request["path"]), request.get("mode", "data"), int(request["limit"])
    with open_input(path, "HDF5 file") as f:
        size = os.fstat(f.fileno()).st_size
        try:
            h = h5py.File(f, "r")
        except (OSError, ValueError, TypeError, KeyError, RuntimeError) as e:
            raise DatasetError(f"cannot read {path} as HDF5 ({' '.join(str(e).split())[:200]})") from e
        try:
            _stream(h, path, mode, min(limit, size * MAX_RATIO + (1 << 20)), size, out)
        except (OSError, ValueError, TypeError, KeyError, RuntimeError, UnicodeDecodeError) as e:
            raise DatasetError(f"cannot read {path} as HDF5 ({' '.join(str(e).split())[:200]})") from e
        finally:
            h.close()


def _stream(h: Any, path: str, mode: str, bound: int, size: int, out: IO[bytes]) -> None:
    links = _links(h, path)
    attrs = _attrs(h)
    if mode == "attrs":
        answer(out, {"attrs": attrs})
        return
    numbers, strings, skipped = _datasets(h, links, path, bound, size)
    text = {name: _strings(h[name]) for name in strings}
    answer(out, {"attrs": attrs, "groups": sorted(n for n, kind in links.items() if kind == "group"),
                 "arrays": [{"name": n, "dtype": h[n].dtype.str, "shape": list(h[n].shape)} for n in numbers],
                 "strings": text, "skipped": skipped})
    for name in numbers:
        for block in _slabs(h[name]):
            if mode == "data":
                out.write(memoryview(np.ascontiguousarray(block)).cast("B"))


def _links(h: Any, path: str) -> dict[str, str]:
    """Every object of the file by name: ``group`` or ``dataset``; an external link is refused."""
    import h5py

    found: dict[str, str] = {}
    external: list[tuple[str, str]] = []

    def visit(name: str, link: Any) -> None:  # raising inside h5py's visit is not safe: collect, then refuse
        if isinstance(link, h5py.ExternalLink):
            external.append((name, str(link.filename)))
        elif isinstance(link, h5py.HardLink):
            found[name] = "group" if isinstance(h.get(name), h5py.Group) else "dataset"

    h.visititems_links(visit)
    if external:
        raise DatasetError(f"{path}: {external[0][0]!r} is an external link to {external[0][1]!r}; seqnet reads no "
                           "other file through an HDF5 file")
    return found


def _attrs(h: Any) -> dict[str, Any]:
    """The root attributes that are text or a number (others are skipped)."""
    out: dict[str, Any] = {}
    for key in list(h.attrs)[:1000]:
        try:
            value = h.attrs[key]
        except (OSError, TypeError, ValueError, KeyError):
            continue
        if isinstance(value, bytes) and len(value) <= MAX_ATTR:
            value = value.decode("utf-8", "replace")
        if isinstance(value, np.generic) and value.dtype.kind in "biuf":
            value = value.item()
        if isinstance(value, (str, int, float, bool)) and (not isinstance(value, str) or len(value) <= MAX_ATTR):
            out[key] = value if not isinstance(value, float) or math.isfinite(value) else None
    return out


def _datasets(h: Any, links: dict[str, str], path: str, bound: int,
              size: int) -> tuple[list[str], list[str], list[str]]:
    """The numeric and the string datasets (checked), and the names of those skipped."""
    import h5py

    numbers, strings, skipped = [], [], []
    for name, kind in sorted(links.items()):
        if kind != "dataset":
            continue
        ds = h[name]
        _check_layout(ds, name, path, bound, size)
        if h5py.check_string_dtype(ds.dtype) is not None:
            strings.append(name)
        elif ds.dtype.kind in "biuf" and ds.dtype.fields is None and ds.dtype.subdtype is None:
            numbers.append(name)
        else:
            skipped.append(name)
    return numbers, strings, skipped


def _check_layout(ds: Any, name: str, path: str, bound: int, size: int) -> None:
    """Refuse virtual or external storage, and a declared size beyond what the file can hold."""
    import h5py

    plist = ds.id.get_create_plist()
    layout = plist.get_layout()
    if layout == h5py.h5d.VIRTUAL:
        raise DatasetError(f"{path}: dataset {name!r} is virtual (it maps other files); seqnet reads no other file "
                           "through an HDF5 file")
    if plist.get_external_count() > 0:
        raise DatasetError(f"{path}: dataset {name!r} keeps its data in external files; seqnet reads no other file "
                           "through an HDF5 file")
    vlen = h5py.check_string_dtype(ds.dtype) is not None and ds.dtype.kind == "O"
    need = math.prod(ds.shape or ()) * (16 if vlen else ds.dtype.itemsize)
    limit = size if layout in (h5py.h5d.CONTIGUOUS, h5py.h5d.COMPACT) or vlen else bound
    if need > min(limit, bound):
        raise DatasetError(f"{path}: dataset {name!r} declares {tuple(ds.shape)} of {ds.dtype} ({need} bytes), "
                           f"more than the file's {size} bytes can hold")


def _strings(ds: Any) -> list[str]:
    """A string dataset as a flat list of str (UTF-8)."""
    values = np.asarray(ds[()], dtype=object).ravel()
    return [v.decode("utf-8") if isinstance(v, bytes) else str(v) for v in values]


def _slabs(ds: Any) -> Any:
    """The dataset in row slabs of at most :data:`SLAB` bytes (a 0-d one whole)."""
    if ds.ndim == 0:
        yield np.asarray(ds[()])
        return
    row = max(1, math.prod(ds.shape[1:]) * ds.dtype.itemsize)
    step = max(1, SLAB // row)
    for a in range(0, ds.shape[0], step):
        yield ds[a : a + step]
