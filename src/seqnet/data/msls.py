"""Mapillary Street-Level Sequences (MSLS) city folders → a dataset.

MSLS's layout (mapillary/mapillary_sls, README and ``datasets/msls.py``)::

    ROOT/train_val/<city>/database|query/
        postprocessed.csv   ,key,easting,northing,unique_cluster,control_panel,night,view_direction
        raw.csv             ,key,lon,lat,ca,captured_at,pano
        seq_info.csv        ,key,sequence_key,frame_number
        images/<key>.jpg
    ROOT/test/<city>/...    seq_info.csv and images only (no positions: the test cities' are withheld)

The first, unnamed column is pandas' row index. An image's place is ``easting, northing``
(UTM metres) of ``postprocessed.csv`` (``lat, lon`` of ``raw.csv`` through :mod:`seqnet.data.gps`
when there is no ``postprocessed.csv``); ``seq_info.csv`` gives the order and the sequences. As MSLS
arranges them (``MSLS.arange_as_seq``), a sequence is a run of consecutive rows with one
``sequence_key`` and frame numbers that rise by one; every image gets the half-open bounds of its
run. Descriptors are matched to images by key (names from HDF5 ``names``, a names file, or the
``images/`` folder in VPR-methods-evaluation's sorted-glob order).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ..core.errors import ConfigError, DatasetError
from ..core.provenance import check_same
from ..security.limits import INDEX_MAX
from ..security.text import shown
from .convert import POSITION_MAX, assemble_dataset, match_names, names_flag, read_csv_rows, runs_to_bounds
from .presets import get_preset
from .readers import read_descriptor_file, read_names, read_provenance
from .traverse import Dataset, Traverse

SIDES = {"reference": "database", "query": "query"}  # seqnet side → MSLS folder
SUBDIRS = ("train_val", "test")
CITY_FOLDERS = {"copenhagen": "cph", "san-francisco": "sf", "sanfrancisco": "sf", "san_francisco": "sf"}
CITY_GROUPS = {"paper-train": "train_cities", "paper-val": "val_cities", "paper-test": "test_cities"}
ROLES = {"train_cities": "train", "val_cities": "val", "test_cities": "test"}


def city_folder(city: str) -> str:
    """MSLS's folder name of ``city`` (``copenhagen`` → ``cph``, ``san-francisco`` → ``sf``)."""
    return CITY_FOLDERS.get(city.lower(), city.lower())


def expand_cities(cities: list[str]) -> list[str]:
    """MSLS folder names of ``cities``; a group (``paper-train``, ``paper-val``, ``paper-test``) stands for the
    paper's cities of that role (the ``msls`` preset)."""
    preset = get_preset("msls")
    out: list[str] = []
    for c in cities:
        out += [city_folder(x) for x in preset[CITY_GROUPS[c]]] if c in CITY_GROUPS else [city_folder(c)]
    dup = next((c for i, c in enumerate(out) if c in out[:i]), None)
    if dup is not None:
        raise ConfigError(f"MSLS city {dup!r} is given twice")
    return out


def paper_role(city: str) -> str | None:
    """``train`` / ``val`` / ``test`` when ``city`` (a folder name) is one of the paper's MSLS cities."""
    preset = get_preset("msls")
    return next((role for key, role in ROLES.items() if city in [city_folder(c) for c in preset[key]]), None)


def find_city(root: str | Path, city: str) -> Path:
    """The folder of ``city`` under an MSLS root (``train_val/<city>`` or ``test/<city>``), or ``root`` itself
    when it is that city's folder (holding ``database/`` and ``query/``)."""
    r = Path(root)
    if r.name == city and all((r / s).is_dir() for s in SIDES.values()):
        return r
    for sub in SUBDIRS:
        if (r / sub / city).is_dir():
            return r / sub / city
    found = sorted(p.name for sub in SUBDIRS if (r / sub).is_dir() for p in (r / sub).iterdir() if p.is_dir())
    raise DatasetError(f"MSLS city {city!r} not found under {r} (looked in {', '.join(SUBDIRS)}; found: "
                       f"{', '.join(shown(f) for f in found[:12]) or 'no city folders'}); hint: ROOT is the folder "
                       "holding train_val/")


@dataclasses.dataclass(frozen=True)
class MslsSide:
    """One MSLS ``database`` or ``query`` folder, in ``seq_info.csv`` order."""

    keys: list[str]
    positions: np.ndarray  # [N, 2] easting, northing (metres)
    seq_bounds: np.ndarray  # [N, 2] half-open run of each image


def _columns(path: Path, wanted: tuple[str, ...]) -> tuple[list[tuple[int, list[str]]], dict[str, int]]:
    header, rows = read_csv_rows(path)
    missing = [c for c in wanted if c not in header]
    if missing:
        raise DatasetError(f"{path}: no column {', '.join(map(repr, missing))} (header: {header}); MSLS's "
                           f"{path.name} has {', '.join(wanted)}")
    col = {c: header.index(c) for c in wanted}
    for line, r in rows:
        if len(r) < len(header):
            raise DatasetError(f"{path}, line {line}: {len(r)} fields, but the header has {len(header)}")
    return rows, col


def _keyed(path: Path, rows: list[tuple[int, list[str]]], col: int) -> dict[str, int]:
    """``key → row index``; a repeated key is refused with both lines."""
    seen: dict[str, int] = {}
    for i, (line, r) in enumerate(rows):
        key = r[col].strip()
        if not key or not key.isprintable() or any(c in key for c in "/\\") or key in (".", ".."):
            raise DatasetError(f"{path}, line {line}: key {key[:80]!r} is not an image key (MSLS names images "
                               "images/<key>.jpg: a printable name without '/')")
        if key in seen:
            raise DatasetError(f"{path}: key {key!r} on lines {rows[seen[key]][0]} and {line} (keys are unique)")
        seen[key] = i
    return seen


def _numbers(path: Path, rows: list, idx: list[int], cols: list[int], names: list[str], kind: type) -> np.ndarray:
    """The columns ``cols`` of the rows ``idx`` as ``kind`` (float: finite, within ±:data:`POSITION_MAX`; int:
    a frame number in 0..:data:`INDEX_MAX`); :class:`DatasetError` naming the line otherwise."""
    out = np.empty((len(idx), len(cols)), dtype=np.float64 if kind is float else np.int64)
    lo, hi = (-POSITION_MAX, POSITION_MAX) if kind is float else (0, INDEX_MAX)
    for o, i in enumerate(idx):
        line, r = rows[i]
        try:
            vals = [kind(r[c]) for c in cols]
        except ValueError:
            vals = [None]
        if not all(v is not None and lo <= v <= hi for v in vals):  # NaN fails too
            span = f"finite, within ±{hi:g}" if kind is float else f"in {lo}..{hi}"
            raise DatasetError(f"{path}, line {line}: {'/'.join(names)} must be {kind.__name__} numbers ({span}), "
                               f"got {[r[c][:40] for c in cols]}")
        out[o] = vals
    return out


def _positions(folder: Path, keys: list[str]) -> np.ndarray:
    """``[N, 2]`` easting/northing of ``keys`` from ``postprocessed.csv`` (else ``raw.csv`` lat/lon → UTM)."""
    post, raw = folder / "postprocessed.csv", folder / "raw.csv"
    path, wanted = (post, ("key", "easting", "northing")) if post.is_file() else (raw, ("key", "lat", "lon"))
    if not path.is_file():
        raise DatasetError(f"{folder}: no postprocessed.csv or raw.csv, so no positions (MSLS withholds the test "
                           "cities' positions); hint: use a train_val city")
    rows, col = _columns(path, wanted)
    table = _keyed(path, rows, col["key"])
    missing = [k for k in keys if k not in table]
    extra = sorted(set(table) - set(keys))
    if missing or extra:
        what = f"seq_info.csv key {missing[0]!r} is not in {path.name}" if missing else \
            f"{path.name} key {extra[0]!r} is not in seq_info.csv"
        raise DatasetError(f"{folder}: {what} ({len(missing)} missing, {len(extra)} extra); the files list the "
                           "same images")
    vals = _numbers(path, rows, [table[k] for k in keys], [col[c] for c in wanted[1:]], list(wanted[1:]), float)
    if path == post:
        return vals
    from .utm import latlon_to_utm

    return latlon_to_utm(vals[:, 0], vals[:, 1], str(path))[0]


def read_msls_side(folder: str | Path) -> MslsSide:
    """Keys, positions and sequence bounds of one MSLS ``database`` / ``query`` folder."""
    f = Path(folder)
    seq = f / "seq_info.csv"
    if not seq.is_file():
        raise DatasetError(f"{f}: no seq_info.csv (MSLS's {f.name} folder holds seq_info.csv, postprocessed.csv, "
                           "raw.csv and images/)")
    rows, col = _columns(seq, ("key", "sequence_key", "frame_number"))
    table = _keyed(seq, rows, col["key"])
    keys = list(table)
    frames = _numbers(seq, rows, list(range(len(rows))), [col["frame_number"]], ["frame_number"], int)[:, 0]
    seqs = [r[col["sequence_key"]].strip() for _, r in rows]
    breaks = np.r_[True, (np.array(seqs[1:]) != np.array(seqs[:-1])) | (np.diff(frames) != 1)]
    bounds = runs_to_bounds([str(x) for x in np.cumsum(breaks)])
    return MslsSide(keys=keys, positions=_positions(f, keys), seq_bounds=bounds)


def msls_traverse(folder: Path, desc_path: str | Path, names: str | Path | None, label: str,
                  read: dict | None = None) -> Traverse:
    """One side of one city: its images' descriptors (matched by key), positions, names and sequence bounds.
    ``read``: descriptor files already read, by ``(file, names file)`` (one file shared by every city is read
    once)."""
    side = read_msls_side(folder)
    images = folder / "images"
    read = {} if read is None else read
    if (desc_path, names) not in read:
        read[desc_path, names] = (*read_descriptor_file(desc_path, names, beside=True), read_provenance(desc_path))
    desc, desc_names, provenance = read[desc_path, names]
    if desc_names is None:
        if not images.is_dir():
            raise DatasetError(f"{desc_path}: no image names and no {images} folder to take them from; hint: give "
                               f"{names_flag(label)} FILE, an HDF5 file with 'names', or a .npy with its names file "
                               "beside it (FILE.names.txt)")
        desc_names = read_names(images)
        if len(desc_names) != desc.shape[0]:
            raise DatasetError(f"{desc_path}: {desc.shape[0]} descriptors but {len(desc_names)} images in {images} "
                               f"(names are taken from the folder in sorted order); hint: give {names_flag(label)}")
    idx = match_names(side.keys, desc_names, f"{folder / 'seq_info.csv'} vs {desc_path}")
    city = folder.parent.name
    return Traverse(descriptors=np.asarray(desc[idx]), positions=side.positions,
                    names=[f"{city}/{folder.name}/images/{k}.jpg" for k in side.keys], seq_bounds=side.seq_bounds,
                    name=label, provenance=provenance)


def _concat(parts: list[Traverse], label: str) -> Traverse:
    off = np.cumsum([0] + [len(t) for t in parts[:-1]])
    return Traverse(descriptors=np.concatenate([t.descriptors for t in parts]),
                    positions=np.concatenate([t.positions for t in parts]),
                    names=[n for t in parts for n in t.names or []],
                    seq_bounds=np.concatenate([t.seq_bounds + o for t, o in zip(parts, off, strict=True)]),
                    name=label, provenance=parts[0].provenance)


def _per_city(files: list[str] | None, n: int, what: str) -> list:
    if not files:
        return [None] * n
    if len(files) not in (1, n):
        raise ConfigError(f"{len(files)} {what} for {n} MSLS cities; give one per --city (or one for all)")
    return files * n if len(files) == 1 else list(files)


def dataset_from_msls(root: str | Path, cities: list[str], ref_desc: list[str], query_desc: list[str],
                      ref_names: list[str] | None = None, query_names: list[str] | None = None,
                      radius: float | None = None, name: str | None = None, extra: dict | None = None,
                      allow_mismatch: bool = False) -> Dataset:
    """A dataset of MSLS cities (database = reference, query = query), one split per city.

    A split is named by the city's role in the paper (``train`` melbourne, ``val`` austin, ``test`` one of
    amman, boston, sf, copenhagen; a second test city: ``test:<city>``), else by the city; the ``msls``
    preset gives the radius (20 m), the training radii and L / w. Descriptor and names files: one for every
    city (matched by key) or one per city.
    """
    folders = expand_cities(cities)
    descs = {s: _per_city(f, len(folders), f"--{s[:3] if s == 'reference' else s}-desc files")
             for s, f in (("reference", ref_desc), ("query", query_desc))}
    names = {s: _per_city(f, len(folders), "names files") for s, f in (("reference", ref_names),
                                                                       ("query", query_names))}
    sides: dict[str, list[Traverse]] = {"reference": [], "query": []}
    read: dict = {}
    for i, city in enumerate(folders):
        base = find_city(root, city)
        for side, sub in SIDES.items():
            sides[side].append(msls_traverse(base / sub, descs[side][i], names[side][i], f"{side} ({city})", read))
    for parts in sides.values():
        for t in parts[1:]:
            check_same(parts[0].provenance, t.provenance, parts[0].name, t.name, allow_mismatch)
    splits, ro, qo = {}, 0, 0
    for city, r, q in zip(folders, sides["reference"], sides["query"], strict=True):
        role = paper_role(city)
        key = role if role and role not in splits else (f"{role}:{city}" if role else city)
        splits[key] = {"reference": (ro, ro + len(r)), "query": (qo, qo + len(q))}
        ro, qo = ro + len(r), qo + len(q)
    meta = {**(extra or {}), "source": {"format": "msls", "root": str(Path(root).resolve()), "cities": folders}}
    return assemble_dataset(_concat(sides["reference"], "reference"), _concat(sides["query"], "query"), "metres",
                            radius, "msls", splits, name or f"msls-{'-'.join(folders)}", meta,
                            allow_mismatch=allow_mismatch)
