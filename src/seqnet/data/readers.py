"""Reading the files a user brings: descriptor files (``.npy``, HDF5), image-name lists, positions.

One reader per kind of file, used by the dataset directory format and by every converter (one rule everywhere):

* descriptors ``[N, D]``: ``.npy`` (memory-mapped when already native float32) or HDF5 (dataset
  ``descriptors``, never a guessed other one, or hloc's global features; optional ``names``; read in the
  sandbox: :mod:`seqnet.security.hdf5file`); any floating dtype or byte order becomes native float32;
  anything else (strings, objects, integers, pickles) is a :class:`DatasetError` naming the file;
* names: UTF-8 text, one name per line (``\\n``-separated); a name may not contain any other line
  separator (``str.splitlines`` semantics, e.g. U+2028), so what is written reads back the same;
* positions: ``.npy``, or CSV / whitespace-separated text of numbers.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import CountError, DatasetError
from ..core.log import logger
from ..core.provenance import BOUND_KEY, MAX_SIDECAR, REPLACES_KEY, sidecar
from ..security.arrays import read_npy as read_array
from ..security.digests import file_digest
from ..security.hdf5file import Hdf5Contents, read_hdf5
from ..security.inputs import read_text as read_input_text
from ..security.inputs import special_file
from ..security.jsonfile import parse_json, read_json
from .imagefolders import folder_names, list_file

DESCRIPTOR_SUFFIXES = (".npy", ".h5", ".hdf5")
# the characters str.splitlines() breaks lines at
LINE_SEPARATORS = frozenset("\n\r\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029")
MAX_TEXT = 1 << 30  # a text file read whole (names, CSV, timestamps)


def names_file_for(path: str | Path) -> Path:
    """The names text file beside a ``.npy`` of descriptors: ``names.txt`` for ``descriptors.npy`` (a traverse
    directory), else ``<stem>.names.txt`` (what ``seqnet describe --out FILE.npy`` writes)."""
    p = Path(path)
    return p.with_name("names.txt") if p.name == "descriptors.npy" else p.with_name(p.stem + ".names.txt")


def names_beside(path: str | Path) -> tuple[list[str], str] | None:
    """The image names of the ``.npy`` ``path`` kept beside it, and where they came from: the names its
    describe sidecar binds to these descriptors (:func:`bound_names`), else :func:`names_file_for`'s file;
    None when there are neither (or ``path`` is no ``.npy``)."""
    p = Path(path)
    if p.suffix.lower() != ".npy":
        return None
    f, bound = names_file_for(p), bound_names(p)
    if bound is not None:  # the names written with these descriptors (a names file may be a killed run's)
        return check_names(bound, str(sidecar(p))), str(f if f.is_file() else sidecar(p))
    return (read_names(f), str(f)) if f.is_file() else None


def read_descriptor_file(path: str | Path, names_file: str | Path | None = None,
                         mmap: bool = True, beside: bool = False) -> tuple[np.ndarray, list[str] | None]:
    """Descriptors ``[N, D]`` (native float32) and their image names (HDF5 ``names`` or ``names_file``; with
    ``beside``, else the names kept beside a ``.npy``: :func:`names_beside`; else None)."""
    p = Path(path)
    if not p.is_file():
        kind = "directory" if p.is_dir() else special_file(p)
        what = f" (it is a {kind}, not a regular file)" if kind else ""
        raise DatasetError(f"descriptor file not found: {p}{what}")
    suffix = p.suffix.lower()
    if suffix not in DESCRIPTOR_SUFFIXES:
        raise DatasetError(f"descriptor file {p} must be .npy, .h5 or .hdf5 (got {p.suffix or 'no extension'!r})")
    desc, names = (read_array(p, mmap, "descriptor file", kinds="f"), None) if suffix == ".npy" else _read_h5(p)
    desc = as_float32(desc, p)
    src: str | Path = f"{p}:names"
    if names_file is not None:
        names, src = read_names(names_file), names_file
    elif names is None and beside and (found := names_beside(p)) is not None:
        names, src = found
        logger.debug("%s: image names from %s", p, src)
    if names is not None and len(names) != desc.shape[0]:
        raise CountError(f"{src}: {len(names)} names for {desc.shape[0]} descriptors in {p} (must be equal)"
                         f"{transposed_hint(len(names), desc)}{_folder_hint(Path(names_file)) if names_file else ''}",
                         (len(names), int(desc.shape[0])))
    return desc, names


def transposed_hint(n: int, desc: np.ndarray) -> str:
    """``"; transposed? ..."`` when ``desc`` has ``n`` columns (``n`` images expected): a ``[D, N]`` array."""
    if desc.ndim == 2 and desc.shape[1] == n != desc.shape[0]:
        return f"; transposed? the array is [{desc.shape[0]}, {n}]; seqnet expects [N, D] (one row per image)"
    return ""


def _folder_hint(names_file: Path) -> str:
    """For names taken from a folder: where they came from, and VPR-methods-evaluation's list file."""
    if not names_file.is_dir():
        return ""
    lst = list_file(names_file)
    if lst.exists():
        return f"; the names are the lines of {lst}, which must list the descriptors' images in row order"
    return (f"; the names are the folder's .jpg/.jpeg/.png files in sorted order; hint: if the descriptors were "
            f"made from a list of the images, put it at {lst} (VPR-methods-evaluation's list file)")


def warn_unless_unit_rows(desc: np.ndarray, where: str | Path, block: int = 1 << 16) -> None:
    """A warning when some descriptor rows are not L2-normalised: seqnet normalises every row before comparing,
    a tool ranking the rows as saved by L2 distance (VPR-methods-evaluation's faiss IndexFlatL2) then ranks
    otherwise, so its figures differ."""
    for a in range(0, desc.shape[0], block):
        norms = np.sqrt(np.einsum("ij,ij->i", desc[a:a + block], desc[a:a + block], dtype=np.float64))
        bad = np.flatnonzero(np.abs(norms - 1.0) > 1e-3)
        if bad.size:
            logger.warning("%s: row %d has L2 norm %.4g, not 1; seqnet L2-normalises rows before comparing, so its "
                           "R@K differ from a tool's that ranks the rows as saved by L2 distance (VPR-methods-"
                           "evaluation); hint: for that tool's figures give its distances with eval --distances",
                           where, a + int(bad[0]), norms[bad[0]])
            return


def as_float32(desc: np.ndarray, where: Path | str) -> np.ndarray:
    """``desc`` as a native-byte-order float32 ``[N, D]`` array (float32 memory maps kept; ``[N, 1, D]`` squeezed)."""
    if desc.ndim > 2 and sum(n > 1 for n in desc.shape) == 2:  # torch's unsqueeze, stacked [1, D] rows
        logger.info("%s: descriptors of shape %s read as [N, D] (size-1 axes dropped)", where, tuple(desc.shape))
        desc = desc.reshape([n for n in desc.shape if n > 1])
    if desc.ndim != 2:
        raise DatasetError(f"{where}: descriptors must be a 2-D [N, D] array, got shape {tuple(desc.shape)}")
    if desc.dtype.kind != "f":
        raise DatasetError(f"{where}: descriptors must be floating point numbers, got dtype {desc.dtype} "
                           "(hint: save them as float32)")
    if desc.dtype == np.float32 and desc.dtype.isnative:
        return desc
    with np.errstate(over="ignore"):  # float64 beyond float32's range becomes inf: caught by validation
        return np.asarray(desc, dtype=np.float32)


def read_npy(f: Path, mmap: bool = True) -> np.ndarray:
    """A ``.npy`` array of numbers (memory-mapped when ``mmap``), its header checked against the file's bytes
    first; never unpickles (:func:`seqnet.security.arrays.read_npy`)."""
    return read_array(f, mmap, "array")


def _read_h5(p: Path) -> tuple[np.ndarray, list[str] | None]:
    """Descriptors and names of an HDF5 file, read in the sandbox (:func:`seqnet.security.hdf5file.read_hdf5`)."""
    h = read_hdf5(p, "descriptor file")
    if "descriptors" not in h.names() and (hloc := _hloc_names(h)):
        return _read_hloc(h, p, hloc)
    desc = h.arrays[_h5_descriptor_key(h, p)]
    names = _h5_names(h, p) if "names" in h.names() else None
    return desc, names


HLOC_KEY = "global_descriptor"  # hloc's global features: one group per image name holding this dataset


def _hloc_names(h: Hdf5Contents) -> list[str]:
    """The image names of an hloc global-feature file (groups, nested by the '/' in a name, holding
    ``global_descriptor``), sorted as hloc's image lists are; [] for another layout."""
    suffix = "/" + HLOC_KEY
    return sorted(n[: -len(suffix)] for n in h.arrays if n.endswith(suffix))


def _read_hloc(h: Hdf5Contents, p: Path, names: list[str]) -> tuple[np.ndarray, list[str]]:
    """hloc's ``global-feats-*.h5``: ``[N, D]`` descriptors of its groups ``names`` (:func:`_hloc_names`, sorted
    image-name order), and the names."""
    rows = [h.arrays[f"{n}/{HLOC_KEY}"].ravel() for n in names]
    dims = {len(r) for r in rows}
    if len(dims) != 1:
        raise DatasetError(f"{p}: hloc global descriptors of {len(dims)} different lengths ({sorted(dims)[:4]})")
    logger.info("%s: hloc global features, %d images (sorted by name), D=%d", p, len(rows), dims.pop())
    return np.stack(rows), names


def _h5_descriptor_key(h: Hdf5Contents, p: Path) -> str:
    if "descriptors" in h.names():
        if "descriptors" not in h.arrays:
            raise DatasetError(f"{p}: 'descriptors' is not a dataset of numbers")
        return "descriptors"
    if "descriptors" in h.groups:
        raise DatasetError(f"{p}: 'descriptors' is an HDF5 group, not a dataset")
    raise DatasetError(f"{p}: no dataset 'descriptors' (found: {', '.join(h.names()[:10]) or 'none'}); seqnet does not "
                       "guess which dataset holds the descriptors; hint: name it 'descriptors' ([N, D] floats)")


def _h5_names(h: Hdf5Contents, p: Path) -> list[str]:
    if "names" not in h.strings:
        what = f"{h.arrays['names'].shape} {h.arrays['names'].dtype}" if "names" in h.arrays else "no strings"
        raise DatasetError(f"{p}: 'names' must be a 1-D dataset of strings (got {what})")
    names = h.strings["names"]
    check_names(names, f"{p}:names")
    return names


def check_names(names: list[str], where: str) -> list[str]:
    """Refuse names that cannot round-trip through a names file (line separators) or are duplicated."""
    for i, n in enumerate(names):
        if "\x00" in n:
            raise DatasetError(f"{where}: name {i} {n!r} contains a NUL character, which no file name holds")
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
    for a folder, its images in VPR-methods-evaluation's order (:func:`seqnet.data.imagefolders.folder_names`)."""
    p = Path(path)
    if p.is_dir():
        return check_names(folder_names(p), str(p))
    names = [line.strip() for line in read_text(p, "names file").split("\n") if line.strip()]
    return check_names(names, str(p))


def read_text(p: Path, what: str = "file") -> str:
    """A UTF-8 text file, opened without blocking (:func:`seqnet.security.inputs.read_text`: a FIFO or device
    is refused, never read); :class:`DatasetError` naming the byte where it is not UTF-8. A byte-order mark
    (Excel's "CSV UTF-8") is dropped."""
    return read_input_text(p, MAX_TEXT, what).removeprefix("\ufeff")


def field_separator(line: str) -> str | None:
    """The field separator of a delimited text file, from its first line: the first of ``,``, ``;`` (a spreadsheet
    in a locale with decimal commas), tab (TSV) the line holds; None when it holds none."""
    return next((s for s in (",", ";", "\t") if s in line), None)


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


def read_provenance(path: str | Path) -> dict[str, Any] | None:
    """The provenance record of a descriptor file (HDF5 attribute ``provenance``, or the ``.npy`` sidecar
    :func:`seqnet.core.provenance.sidecar`), or None when it has none; an unreadable one is ignored with a warning."""
    p = Path(path)
    if p.suffix.lower() in (".h5", ".hdf5"):
        try:
            text = read_hdf5(p, "descriptor file", attrs_only=True).attrs.get("provenance")
        except DatasetError:
            return None
        try:
            record = parse_json(text, f"{p}:provenance") if isinstance(text, str) and text else None
        except DatasetError:
            record = None
            logger.warning("ignoring the unreadable provenance of %s", p)
    elif sidecar(p).is_file():
        try:
            record = read_json(sidecar(p), "provenance file", limit=MAX_SIDECAR)
        except DatasetError as e:
            logger.warning("ignoring the unreadable provenance of %s (%s)", p, e)
            return None
        record = _bound(record, p)
        if isinstance(record, dict):
            record.pop(BOUND_KEY, None)
    else:
        return None
    return record if isinstance(record, dict) and "id" in record else None


def _bound(record: Any, p: Path) -> Any:
    """Of a ``.npy``'s sidecar, the record that belongs to the descriptors now in ``p`` (the new one, or the one
    it replaces while a describe run is between its renames); one bound to other descriptors is a
    :class:`DatasetError`. A record without a binding (made elsewhere, or by seqnet 0.2) is returned as it is."""
    if not isinstance(record, dict) or not isinstance(record.get(BOUND_KEY), dict):
        return record
    digest = file_digest(p)
    for cand in (record, record.get(REPLACES_KEY)):
        if isinstance(cand, dict) and isinstance(cand.get(BOUND_KEY), dict) and \
                cand[BOUND_KEY].get("descriptors") == digest:
            return {k: v for k, v in cand.items() if k != REPLACES_KEY}
    raise DatasetError(f"{sidecar(p)} was written for other descriptors than those now in {p} (a describe run "
                       "stopped between writing them?); hint: run the same seqnet describe again to finish it")


def bound_names(path: str | Path) -> list[str] | None:
    """The names a describe ``.npy`` output's sidecar records for the descriptors now in ``path`` (None when
    the sidecar records none)."""
    p = Path(path)
    if not sidecar(p).is_file():
        return None
    record = _bound(read_json(sidecar(p), "provenance file", limit=MAX_SIDECAR), p)
    names = record.get(BOUND_KEY, {}).get("names") if isinstance(record, dict) else None
    return [str(n) for n in names] if isinstance(names, list) else None
