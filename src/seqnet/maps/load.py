"""Opening a map directory: every file checked against ``map.json`` before use, clear errors."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ConfigError, SeqnetError
from ..data.readers import read_names
from ..search.ann import set_search_params
from ..security.arrays import read_npy
from ..security.digests import verify_digests
from ..security.dirs import read_consistent
from ..security.faissfile import read_faiss
from ..security.inputs import inside
from ..security.limits import DIM_MAX, INDEX_MAX, number
from ..sequence.checkpoints import load_model
from .config import MapConfig
from .edges import EDGE_FILE
from .map import Map, MapError, read_meta
from .store import INDEX_FILE


def _array(path: Path, shape: tuple[int, ...] | None, kinds: str) -> np.ndarray:
    """A ``.npy`` memory map (copy-on-write: never written back) of the expected shape and dtype kind."""
    if not path.exists() and not path.is_symlink():  # a FIFO or device there is named by read_npy
        raise MapError(f"map file missing: {path} (hint: rebuild the map with seqnet index build)")
    arr = read_npy(path, "c", "map file", MapError)
    if arr.dtype.kind not in kinds or (shape is not None and arr.shape != shape):
        raise MapError(f"{path}: expected shape {shape} of kind {kinds!r}, got {arr.shape} {arr.dtype} "
                       "(the map is damaged; rebuild it)")
    return arr


def load_map(path: str | Path, device: str | None = None, anchor: str = "") -> Map:
    """Open the map directory ``path`` (written by :func:`seqnet.maps.build` or :func:`seqnet.maps.write_map`);
    ``anchor``: the pinned window step of its anchored matchers (default: its window mode's). A map
    replaced while it is opened is opened again (one version, never a mix)."""
    return read_consistent(Path(path), lambda: _load_map(Path(path), device, anchor), MapError)


def _load_map(path: Path, device: str | None, anchor: str) -> Map:
    meta = read_meta(path)
    check_files(path, meta)
    r, nr = (int(number(meta.get(k), f"{path / 'map.json'}: {k}", 1, INDEX_MAX, MapError)) for k in ("items", "frames"))
    d1, d2 = (int(number(meta.get(k), f"{path / 'map.json'}: {k}", 1, DIM_MAX, MapError))
              for k in ("shortlist_dim", "frame_dim"))
    conf_dict = meta.get("config")
    if not isinstance(conf_dict, dict):
        raise MapError(f"{path / 'map.json'}: missing or bad config")
    arrays: dict[str, Any] = {"shortlist": _array(path / "shortlist.npy", (r, d1), "f"),
                              "frames": _array(path / "frames.npy", (nr, d2), "f"),
                              "items": _array(path / "items.npy", (r,), "iu"),
                              "match_starts": _array(path / "match_starts.npy", (r,), "iu"),
                              "positions": _array(path / "positions.npy", None, "f")}
    check_arrays(path, arrays, nr)
    if (path / EDGE_FILE).is_file():
        arrays["edge_shortlist"] = _array(path / EDGE_FILE, (nr - r, d1), "f")
    if (path / "seq_bounds.npy").is_file():
        arrays["seq_bounds"] = _array(path / "seq_bounds.npy", (nr, 2), "iu")
    if (path / "names.txt").is_file():
        arrays["names"] = read_names(path / "names.txt")
        if len(arrays["names"]) != nr:
            raise MapError(f"{path / 'names.txt'}: {len(arrays['names'])} names for {nr} frames (the map is damaged; "
                           "rebuild it)")
    try:
        conf = MapConfig.from_dict(conf_dict)
    except (ConfigError, TypeError, ValueError) as e:
        raise MapError(f"{path / 'map.json'}: bad config ({e})") from e
    index = None if conf.ann.kind == "flat" else _index(path / INDEX_FILE, conf, r, d1)
    models = _models(path, meta, conf)
    return Map(path, meta, arrays, index, models, device, anchor)


def check_files(path: Path, meta: dict[str, Any], full: bool = False) -> None:
    """Every file the map was written with has its size and sampled hash (``full``: its whole hash) of then;
    a map without checksums (seqnet 0.2) is opened as it is."""
    verify_digests(path, meta.get("checksums") or {}, MapError, "map", "a map is written whole: rebuild it with "
                   "seqnet index build", full)


def check_arrays(path: Path, arrays: dict[str, Any], nr: int) -> None:
    """Positions finite and one per frame; items and window starts inside the frames."""
    pos = arrays["positions"]
    if pos.ndim != 2 or len(pos) != nr or not np.isfinite(pos).all():
        raise MapError(f"{path / 'positions.npy'}: {pos.shape} positions for {nr} frames, or NaN / inf among them "
                       "(the map is damaged; rebuild it)")
    for name in ("items", "match_starts"):
        a = np.asarray(arrays[name])
        if a.size and (a.min() < 0 or a.max() >= nr):
            raise MapError(f"{path / (name + '.npy')}: values in {a.min()}..{a.max()}, outside the map's {nr} "
                           "frames (the map is damaged; rebuild it)")


def _index(file: Path, conf: Any, n: int, d: int) -> Any:
    if not file.exists() and not file.is_symlink():
        raise MapError(f"map file missing: {file} (a {conf.ann.kind} map needs its index)")
    index = read_faiss(file, n, d, "map index", MapError)  # probed in the sandbox; on-disk lists mapped read-only
    set_search_params(index, conf.ann)
    return index


def _models(path: Path, meta: dict[str, Any], conf: Any) -> dict[str, Any]:
    stored = meta.get("models") or {}
    if not isinstance(stored, dict):
        raise MapError(f"{path / 'map.json'}: 'models' must map a role to a file in the map")
    missing = conf.roles() - set(stored)
    if missing:
        raise MapError(f"{path}: the map's {conf.method.name} needs model(s) {sorted(missing)} but stores "
                       f"{sorted(stored) or 'none'}")
    models = {}
    for role, rel in stored.items():
        try:
            models[role] = load_model(inside(path, rel, f"{path / 'map.json'}: model {role!r}", MapError))
        except SeqnetError as e:
            raise MapError(f"{path}: cannot load the map's {role} model ({e})") from e
    return models
