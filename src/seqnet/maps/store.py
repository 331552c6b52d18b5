"""Writing a map directory from arrays: descriptors (chunked, float32 or float16), index, models, manifest.

Layout of a map directory ``MAP/`` (format ``seqnet-map/1``)::

    map.json            format, resolved MapConfig, shapes, dtype, provenance, models, source
    shortlist.npy       [R, D1]  shortlist descriptor of every reference item (float32 / float16)
    frames.npy          [Nr, D2] re-ranking frame descriptor of every reference frame
    items.npy           [R]      frame of each item;  match_starts.npy [R]: its L_m-window start
    positions.npy       [Nr, P]  positions of the frames;  names.txt, seq_bounds.npy (optional)
    edge_shortlist.npy  [E, D1]  shortlist descriptor of the frames that are no item, for a single-frame shortlist
                        whose stored frames are another descriptor (:mod:`seqnet.maps.edges`; optional)
    index.faiss         ANN index over shortlist.npy (absent for ``flat``: exact search over the file)
    models/<role>.pt    the models the descriptors were made with (the map is self-contained)
    pca.npz             a ``--pca D`` dataset's train-split PCA, which reduces query images' descriptors as the
                        map's were (its tag: their provenance id; absent for descriptors reduced by no PCA)
    .seqnet-manifest.json

It is written into a temporary sibling directory under the lock of ``MAP`` and renamed into
place; an existing ``MAP`` is replaced only when seqnet wrote everything in it.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .._version import __version__
from ..core.errors import ConfigError
from ..core.lazy import lazy_module
from ..core.log import logger
from ..core.memmaps import read_rows
from ..core.memory import BLOCK_BYTES as MEMORY_BLOCK
from ..core.npy import write_npy_rows
from ..core.tensors import ArrayLike, to_numpy
from ..search.ann import build_index, save_index
from ..security.arrays import read_npy
from ..security.digests import file_digest
from ..security.dirs import recover_dir, write_dir
from ..security.files import atomic_path, save_npy_atomic, write_json_atomic, write_text_atomic
from ..security.locks import locked
from ..security.ownership import check_replaceable, write_manifest
from ..sequence.checkpoints import save_checkpoint
from .config import MapConfig
from .shards import build_sharded_index, split_rows

torch = lazy_module("torch")

if TYPE_CHECKING:
    from ..describe.pca import PCA
    from ..sequence.model import SeqNet

MAP_FORMAT = "seqnet-map/1"
MAP_JSON = "map.json"
INDEX_FILE = "index.faiss"
PCA_FILE = "pca.npz"
ARRAY_FILES = ("shortlist", "frames", "items", "match_starts", "positions", "seq_bounds", "edge_shortlist")
CHUNK_BYTES = MEMORY_BLOCK // 2  # rows written per chunk


def is_map_file(rel: str) -> bool:
    """Whether ``rel`` (a path inside a map directory) is a file seqnet writes there."""
    parts = rel.split("/")
    if len(parts) == 2:
        return parts[0] == "models" and parts[1].endswith(".pt")
    return rel in (MAP_JSON, INDEX_FILE, PCA_FILE, "index.ivfdata", "names.txt") or \
        rel in {f"{a}.npy" for a in ARRAY_FILES}


@dataclasses.dataclass
class MapArrays:
    """The reference side of a map (numpy arrays or memory maps; torch tensors are accepted).

    Attributes:
        shortlist: ``[R, D1]`` shortlist descriptors of the items.
        frames: ``[Nr, D2]`` re-ranking frame descriptors.
        items: ``[R]`` frame of each item; match_starts: ``[R]`` first frame of its L_m-window.
        positions: ``[Nr, P]``; names: ``Nr`` image names or None; seq_bounds: ``[Nr, 2]`` or None.
        edge_shortlist: ``[E, D1]`` shortlist descriptors of the ``E = Nr - R`` frames that are no item, in frame
            order (:mod:`seqnet.maps.edges`), or None.
    """

    shortlist: ArrayLike
    frames: ArrayLike
    items: np.ndarray
    match_starts: np.ndarray
    positions: np.ndarray
    names: list[str] | None = None
    seq_bounds: np.ndarray | None = None
    edge_shortlist: ArrayLike | None = None

    def check(self, match_len: int) -> None:
        """:class:`ConfigError` naming the first inconsistency."""
        r, nr = len(self.items), len(self.frames)
        if self.shortlist.ndim != 2 or self.frames.ndim != 2 or len(self.shortlist) != r or r == 0:
            raise ConfigError(f"a map needs shortlist [R, D1] and frames [Nr, D2] with R = {r} items > 0, got "
                              f"{tuple(self.shortlist.shape)} and {tuple(self.frames.shape)}")
        starts = np.asarray(self.match_starts)
        if starts.shape != (r,) or (r and (starts.min() < 0 or starts.max() + match_len > nr)):
            raise ConfigError(f"match_starts must be {r} window starts in 0..{nr - match_len} (L_m={match_len})")
        if np.asarray(self.items).min() < 0 or np.asarray(self.items).max() >= nr or len(self.positions) != nr:
            raise ConfigError(f"items must be frames in 0..{nr - 1} and positions [{nr}, P]")
        if self.names is not None and len(self.names) != nr:
            raise ConfigError(f"{len(self.names)} names for {nr} frames")
        e = self.edge_shortlist
        if e is not None and tuple(e.shape) != (nr - r, self.shortlist.shape[1]):
            raise ConfigError(f"edge_shortlist must be [{nr - r}, {self.shortlist.shape[1]}] (a row per frame that "
                              f"is no item), got {tuple(e.shape)}")


def save_array(path: Path, array: ArrayLike, dtype: str, name: str) -> Path:
    """Write ``array`` as ``.npy`` of ``dtype`` in row chunks (memory-bounded; NaN or inf is an error)."""
    shape = tuple(array.shape)

    def blocks() -> Iterator[np.ndarray]:
        step = max(1, CHUNK_BYTES // max(1, 4 * int(np.prod(shape[1:]))))
        for a in range(0, shape[0], step):
            part = array[a : a + step] if isinstance(array, torch.Tensor) else read_rows(array, a, a + step)
            block = np.asarray(to_numpy(part), dtype=np.float32)
            if not np.isfinite(block).all():
                raise ConfigError(f"{name} descriptors hold NaN or inf (rows {a}..{a + len(block) - 1})")
            yield block

    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        write_npy_rows(f, shape, dtype, blocks(), name)
    return path


def write_map(out: str | Path, conf: MapConfig, arrays: MapArrays, models: Mapping[str, SeqNet] | None = None,
              provenance: dict | None = None, info: Mapping[str, Any] | None = None, pca: PCA | None = None) -> Path:
    """Write a map directory (see the module docstring) from ``arrays``; returns its path.

    ``conf`` must be resolved (``seq_len`` and ``match_len`` set); ``provenance`` is that of
    the raw reference descriptors the map was made from, ``info`` is stored under ``source``; ``pca``: the
    ``--pca D`` PCA that reduced them (written as ``pca.npz``, tagged with ``provenance``'s id).
    """
    out = Path(out)
    if conf.seq_len is None or conf.match_len is None:
        raise ConfigError("write_map needs a resolved MapConfig (seq_len and match_len set)")
    arrays.check(conf.match_len)
    with locked(out):
        recover_dir(out)
        check_replaceable(out, "map", is_map_file)
        write_dir(out, lambda tmp: _write(tmp, conf, arrays, dict(models or {}), provenance, dict(info or {}), pca))
    logger.info("wrote map %s (%d items, %d frames, index %s)", out, len(arrays.items), len(arrays.frames),
                conf.ann.kind)
    return out


def _write(root: Path, conf: MapConfig, a: MapArrays, models: dict[str, SeqNet], provenance: dict | None,
           info: dict[str, Any], pca: PCA | None) -> None:
    shortlist = save_array(root / "shortlist.npy", a.shortlist, conf.dtype, "shortlist")
    save_array(root / "frames.npy", a.frames, conf.dtype, "frame")
    if a.edge_shortlist is not None:
        save_array(root / "edge_shortlist.npy", a.edge_shortlist, conf.dtype, "shortlist")
    for name in ("items", "match_starts"):
        save_npy_atomic(root / f"{name}.npy", np.asarray(getattr(a, name), dtype=np.int64))
    save_npy_atomic(root / "positions.npy", np.asarray(a.positions, dtype=np.float64).reshape(len(a.frames), -1))
    if a.seq_bounds is not None:
        save_npy_atomic(root / "seq_bounds.npy", np.asarray(a.seq_bounds, dtype=np.int64))
    if a.names is not None:
        write_text_atomic(root / "names.txt", "\n".join(a.names) + "\n")
    t0 = time.perf_counter()
    if conf.ann.kind != "flat" and conf.shards > 1:  # IVF lists built in shards, merged on disk (index.ivfdata)
        x = read_npy(shortlist, True, "map file", ConfigError)
        build_sharded_index([x[a:b] for a, b in split_rows(len(x), conf.shards)], conf.ann, root / INDEX_FILE)
    elif conf.ann.kind != "flat":  # built over the stored (possibly float16-rounded) values
        save_index(build_index(read_npy(shortlist, True, "map file", ConfigError), conf.ann), root / INDEX_FILE)
    info["index_seconds"] = round(time.perf_counter() - t0, 3)
    for role, model in models.items():
        save_checkpoint(root / "models" / f"{role}.pt", model)
    if pca is not None:
        pca.save(root / PCA_FILE, tag=(provenance or {}).get("id"))
    checksums = {p.relative_to(root).as_posix(): file_digest(p, full=True) for p in sorted(root.rglob("*"))
                 if p.is_file()}  # sampled hashes checked on every open, full ones by seqnet index check --full
    meta = {"format": MAP_FORMAT, "seqnet_version": __version__, "config": conf.to_dict(), "checksums": checksums,
            "items": len(a.items), "frames": len(a.frames), "shortlist_dim": int(a.shortlist.shape[1]),
            "frame_dim": int(a.frames.shape[1]), "input_dim": info.pop("input_dim", None),
            "provenance": provenance, "models": {r: f"models/{r}.pt" for r in models}, "source": info}
    if pca is not None:
        meta["pca"] = PCA_FILE
    if (selection := info.pop("selection", None)) is not None:  # HVPR's settings chosen on val (seqnet.maps.chosen)
        meta["selection"] = selection
    write_json_atomic(root / MAP_JSON, meta)
    write_manifest(root, "map", [p for p in root.rglob("*") if p.is_file()])

