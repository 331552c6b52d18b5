"""Reading the files a user brings: descriptor files (``.npy``, HDF5), image-name lists, positions.

One reader per kind of file, used by the dataset directory format and by every converter, so the
rules are the same everywhere:

* descriptors ``[N, D]``: ``.npy`` (memory-mapped when already native float32) or HDF5 (dataset
  ``descriptors``, or the only 2-D numeric dataset, and optional ``names``); any floating dtype or
  byte order becomes native float32; anything else (strings, objects, integers, pickles) is a
  :class:`DatasetError` naming the file;
* names: UTF-8 text, one name per line (``\\n``-separated); a name may not contain any other line
  separator (``str.splitlines`` semantics, e.g. U+2028), so what is written reads back the same;
* positions: ``.npy``, or CSV / whitespace-separated text of numbers.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ..core.errors import DatasetError
from ..core.utils import logger
from ..security.inputs import special_file

DESCRIPTOR_SUFFIXES = (".npy", ".h5", ".hdf5")
# the characters str.splitlines() breaks lines at
LINE_SEPARATORS = frozenset("\n\r\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029")


def read_descriptor_file(path: str | Path, names_file: str | Path | None = None,
                         mmap: bool = True) -> tuple[np.ndarray, list[str] | None]:
    """Descriptors ``[N, D]`` (native float32) and their image names (HDF5 ``names`` or ``names_file``; else None)."""
    p = Path(path)
    if not p.is_file():
        kind = "directory" if p.is_dir() else special_file(p)
        what = f" (it is a {kind}, not a regular file)" if kind else ""
        raise DatasetError(f"descriptor file not found: {p}{what}")
    suffix = p.suffix.lower()
    if suffix not in DESCRIPTOR_SUFFIXES:
        raise DatasetError(f"descriptor file {p} must be .npy, .h5 or .hdf5 (got {p.suffix or 'no extension'!r})")
    desc, names = (read_npy(p, mmap), None) if suffix == ".npy" else _read_h5(p)
    desc = as_float32(desc, p)
    if names_file is not None:
        names = read_names(names_file)
    if names is not None and len(names) != desc.shape[0]:
        src = names_file or f"{p}:names"
        raise DatasetError(f"{src}: {len(names)} names for {desc.shape[0]} descriptors in {p} (must be equal)")
    return desc, names


def as_float32(desc: np.ndarray, where: Path | str) -> np.ndarray:
    """``desc`` as a native-byte-order float32 ``[N, D]`` array (memory maps of float32 are kept)."""
    if desc.ndim != 2:
        raise DatasetError(f"{where}: descriptors must be a 2-D [N, D] array, got shape {tuple(desc.shape)}")
    if desc.dtype.kind != "f":
        raise DatasetError(f"{where}: descriptors must be floating point numbers, got dtype {desc.dtype} "
                           "(hint: save them as float32)")
    if desc.dtype == np.float32 and desc.dtype.isnative:
        return desc
    with np.errstate(over="ignore"):
        out = np.asarray(desc, dtype=np.float32)  # float64 beyond float32's range becomes inf: caught by validation
    return out


def read_npy(f: Path, mmap: bool = True) -> np.ndarray:
    """A ``.npy`` array (memory-mapped when ``mmap``); never unpickles."""
    with open(f, "rb") as fh:
        magic = fh.read(6)
    if magic != b"\x93NUMPY":
        what = "not in .npy format (no NumPy header)"
        if not magic:
            what = "empty"
        elif magic.startswith(b"PK"):
            what = "a .npz archive"
        raise DatasetError(f"cannot read {f} as a .npy array: the file is {what}")
    try:
        arr = np.load(f, mmap_mode="r" if mmap else None, allow_pickle=False)
    except (ValueError, OSError, EOFError) as e:
        msg = "it holds Python objects (pickled data), not numbers" if "pickle" in str(e) else str(e)
        raise DatasetError(f"cannot read {f} as a .npy array ({msg})") from e
    if not isinstance(arr, np.ndarray):  # pragma: no cover - np.load only returns arrays after the magic check
        raise DatasetError(f"cannot read {f} as a .npy array")
    return arr


def _read_h5(p: Path) -> tuple[np.ndarray, list[str] | None]:
    import h5py

    try:
        with h5py.File(p, "r") as h:
            if "descriptors" not in h and (hloc := _hloc_names(h)):
                return _read_hloc(h, p, hloc)
            desc = np.asarray(h[_h5_descriptor_key(h, p)][()])
            names = _h5_names(h, p) if "names" in h else None
    except (OSError, TypeError, ValueError, KeyError) as e:
        raise DatasetError(f"cannot read {p} as HDF5 ({' '.join(str(e).split())})") from e
    return desc, names


HLOC_KEY = "global_descriptor"  # hloc's global features: one group per image name holding this dataset


def _hloc_names(h) -> list[str]:  # noqa: ANN001 - h5py.File
    """The image names of an hloc global-feature file (groups, nested by the '/' in a name, holding
    ``global_descriptor``), sorted as hloc's image lists are; [] for another layout."""
    import h5py

    found: list[str] = []
    h.visititems(lambda name, node: found.append(name) if isinstance(node, h5py.Group) and HLOC_KEY in node
                 else None)
    return sorted(found)


def _read_hloc(h, p: Path, names: list[str]) -> tuple[np.ndarray, list[str]]:  # noqa: ANN001 - h5py.File
    """hloc's ``global-feats-*.h5``: ``[N, D]`` descriptors of its groups ``names`` (:func:`_hloc_names`, sorted
    image-name order), and the names."""
    rows = [np.asarray(h[n][HLOC_KEY][()]).ravel() for n in names]
    dims = {len(r) for r in rows}
    if len(dims) != 1:
        raise DatasetError(f"{p}: hloc global descriptors of {len(dims)} different lengths ({sorted(dims)[:4]})")
    logger.info("%s: hloc global features, %d images (sorted by name), D=%d", p, len(rows), dims.pop())
    return np.stack(rows), names


def _h5_descriptor_key(h, p: Path) -> str:  # noqa: ANN001 - h5py.File
    import h5py

    if "descriptors" in h:
        if not isinstance(h["descriptors"], h5py.Dataset):
            raise DatasetError(f"{p}: 'descriptors' is an HDF5 group, not a dataset")
        return "descriptors"
    two_d = [k for k, v in h.items() if isinstance(v, h5py.Dataset) and v.ndim == 2 and k != "names"]
    if len(two_d) != 1:
        raise DatasetError(f"{p}: no dataset 'descriptors' and {len(two_d)} other 2-D datasets "
                           f"(found: {list(h.keys())}); hint: name the descriptor dataset 'descriptors'")
    return two_d[0]


def _h5_names(h, p: Path) -> list[str]:  # noqa: ANN001 - h5py.File
    import h5py

    node = h["names"]
    if not isinstance(node, h5py.Dataset) or node.ndim != 1 or node.dtype.kind not in "OSU":
        raise DatasetError(f"{p}: 'names' must be a 1-D dataset of strings (got {type(node).__name__} "
                           f"{getattr(node, 'shape', '')} {getattr(node, 'dtype', '')})")
    try:
        names = [n.decode("utf-8") if isinstance(n, bytes) else str(n) for n in node[()]]
    except UnicodeDecodeError as e:
        raise DatasetError(f"{p}: 'names' are not UTF-8 text ({e.reason})") from e
    check_names(names, f"{p}:names")
    return names


def check_names(names: list[str], where: str) -> list[str]:
    """Refuse names that cannot round-trip through a names file (line separators) or are duplicated."""
    for i, n in enumerate(names):
        if not LINE_SEPARATORS.isdisjoint(n):
            raise DatasetError(f"{where}: name {i} {n!r} contains a line separator; names are one per line")
        if n != n.strip() or not n:
            raise DatasetError(f"{where}: name {i} {n!r} is empty or starts or ends with whitespace, which a names "
                               "file does not keep (names are stripped when read)")
    seen: dict[str, int] = {}
    for i, n in enumerate(names):
        if n in seen:
            raise DatasetError(f"{where}: name {n!r} appears twice (entries {seen[n]} and {i}); names must be unique")
        seen[n] = i
    return names


def read_names(path: str | Path) -> list[str]:
    """Image names, one per non-blank ``\\n``-separated line of a UTF-8 text file (surrounding spaces removed);
    for a folder, its images in VPR-methods-evaluation's order (:func:`folder_names`)."""
    p = Path(path)
    if p.is_dir():
        return folder_names(p)
    if not p.is_file():
        raise DatasetError(f"names file not found: {p}")
    names = [line.strip() for line in read_text(p).split("\n") if line.strip()]
    return check_names(names, str(p))


def folder_names(folder: Path) -> list[str]:
    """The ``.jpg`` images under ``folder`` (relative paths) in the order VPR-methods-evaluation and the
    Visual Geo-localization Benchmark describe them: ``sorted(glob(folder/**/*.jpg, recursive=True))``,
    so their saved ``database_descriptors.npy`` / ``queries_descriptors.npy`` rows get their names."""
    import glob
    import os

    paths = sorted(glob.glob(os.path.join(str(folder), "**", "*.jpg"), recursive=True))
    if not paths:
        raise DatasetError(f"{folder}: no .jpg images under it (names are read as sorted(glob('**/*.jpg')))")
    return check_names([os.path.relpath(q, folder) for q in paths], str(folder))


def read_text(p: Path) -> str:
    """A UTF-8 text file; :class:`DatasetError` naming the byte where it is not UTF-8."""
    try:
        return p.read_bytes().decode("utf-8")
    except UnicodeDecodeError as e:
        raise DatasetError(f"{p}: not UTF-8 text ({e.reason} at byte {e.start})") from e


def read_positions_file(f: Path) -> np.ndarray:
    """Positions ``[N, P]`` from ``.npy`` or a text file of numbers (comma-separated for ``.csv``)."""
    if f.suffix == ".npy":
        return read_npy(f, mmap=False)
    text = read_text(f)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # an empty file is reported below, not warned about
            arr = np.loadtxt(text.splitlines(), delimiter="," if f.suffix == ".csv" else None, ndmin=2)
    except ValueError as e:
        raise DatasetError(f"cannot parse {f} as numbers ({' '.join(str(e).split())})") from e
    if arr.size == 0:
        raise DatasetError(f"{f} holds no positions (the file is empty)")
    return arr
