"""``seqnet describe merge SHARD... --out OUT``: the shard outputs of one ``seqnet describe --shard k/N`` run
into the file an unsharded run writes (same descriptors, byte for byte, same names, same provenance).

The shards must have one provenance (settings, fitted state, D), one image list, the same N, every k
exactly once and ranges that tile the list; anything else is refused naming the file and the value.
The merge streams: the shards are memory-mapped (``.npy``) or read in blocks (HDF5) and copied in
blocks of :data:`BLOCK_ROWS` rows, never held in memory whole.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import os
import re
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from ..core.errors import ConfigError, DatasetError
from ..core.log import logger
from ..core.provenance import ProvenanceError, differences
from ..core.provenance import sidecar as provenance_sidecar
from ..data.readers import bound_names, read_names, read_npy, read_provenance
from ..security.dirs import remove_dead_temps
from ..security.hdf5file import check_hdf5
from ..security.limits import INDEX_MAX, number
from ..security.locks import locked
from .output import OUT_SUFFIXES, check_sidecars, names_file_for, write_output
from .shards import SHARD_KEY

BLOCK_ROWS = 65536


@dataclasses.dataclass
class ShardFile:
    """One shard output: its path, provenance without the shard record (``prov``), the shard record,
    the HDF5 ``config`` attribute (None for ``.npy``), its names and ``shape = (n, D)``."""

    path: Path
    prov: dict[str, Any]
    shard: dict[str, Any]
    config: str | None
    names: list[str]
    shape: tuple[int, int]

    def blocks(self, rows: int = BLOCK_ROWS) -> Iterator[np.ndarray]:
        """The descriptors in consecutive blocks ``[<= rows, D]`` (memory-mapped or read block by block)."""
        if self.config is None:
            arr = read_npy(self.path, mmap=True)
            for a in range(0, len(arr), rows):
                yield arr[a:a + rows]
            return
        with h5py.File(self.path, "r") as h:
            ds = h["descriptors"]
            for a in range(0, ds.shape[0], rows):
                yield ds[a:a + rows]


def read_shard(path: str | os.PathLike[str]) -> ShardFile:
    """The header of a shard output (descriptors are not read); :class:`ConfigError` when it is none."""
    p = Path(path)
    if p.suffix.lower() not in OUT_SUFFIXES or not p.is_file():
        raise DatasetError(f"shard {p} is not a describe output file ({', '.join(OUT_SUFFIXES)})")
    prov = read_provenance(p)
    if not prov or not isinstance(prov.get(SHARD_KEY), dict):
        raise ConfigError(f"{p} is not a shard output (its provenance has no {SHARD_KEY!r} record); hint: merge the "
                          "outputs of seqnet describe --shard k/N")
    shard = shard_record(prov.pop(SHARD_KEY), p)
    try:
        if p.suffix.lower() == ".npy":
            names = bound_names(p) or read_names(names_file_for(p))
            shape, config = read_npy(p, mmap=True).shape, None
        else:
            check_hdf5(p, "shard")  # libhdf5 meets a stranger's file in the sandbox first
            with h5py.File(p, "r") as h:
                shape, config = h["descriptors"].shape, str(h.attrs["config"])
                names = [n.decode() if isinstance(n, bytes) else str(n) for n in h["names"][()]]
    except (OSError, KeyError, ValueError, TypeError) as e:
        raise DatasetError(f"cannot read shard {p} ({' '.join(str(e).split())})") from e
    if len(shape) != 2 or len(names) != shape[0]:
        raise DatasetError(f"shard {p}: {len(names)} names for descriptors of shape {tuple(shape)}")
    return ShardFile(p, prov, shard, config, names, (int(shape[0]), int(shape[1])))


def shard_record(value: dict[str, Any], p: Path) -> dict[str, Any]:
    """The shard record of ``p``'s provenance (read from the file), every field of its type and in its range;
    :class:`DatasetError` naming the field otherwise."""
    where = f"shard {p}: the {SHARD_KEY!r} record's"
    count = number(value.get("count"), f"{where} count", 1, INDEX_MAX)
    images = number(value.get("images"), f"{where} images", 1, INDEX_MAX)
    frames = value.get("frames")
    if not isinstance(frames, list) or len(frames) != 2:
        raise DatasetError(f"{where} frames must be [first, end], got {str(frames)[:60]}")
    first = number(frames[0], f"{where} frames[0]", 0, images - 1)
    sha = value.get("list_sha1")
    if not isinstance(sha, str) or not re.fullmatch(r"[0-9a-f]{1,64}", sha):
        raise DatasetError(f"{where} list_sha1 must be a hexadecimal hash, got {str(sha)[:60]!r}")
    return {"index": number(value.get("index"), f"{where} index", 0, count - 1), "count": count,
            "frames": [first, number(frames[1], f"{where} frames[1]", first + 1, images)], "images": images,
            "batch_size": number(value.get("batch_size"), f"{where} batch_size", 1, INDEX_MAX), "list_sha1": sha}


def check_shards(shards: Sequence[ShardFile]) -> list[ShardFile]:
    """The shards in order of their index, after checking they are one complete run (see the module
    docstring): :class:`ProvenanceError` / :class:`ConfigError` naming the first problem."""
    first = shards[0]
    for s in shards[1:]:
        if s.prov != first.prov:
            diff = differences(s.prov, first.prov) or ["their provenance records differ"]
            raise ProvenanceError(f"shards {s.path} and {first.path} were made differently: {'; '.join(diff)}; "
                                  "hint: describe every shard with the same options")
        for key in ("count", "images", "list_sha1", "batch_size"):
            if s.shard.get(key) != first.shard.get(key):
                raise ConfigError(f"shard {s.path} has {key} {s.shard.get(key)!r} but {first.path} has "
                                  f"{first.shard.get(key)!r}: they are not shards of one run (hint: the same images, "
                                  "options and N for every shard)")
        if s.config != first.config:
            raise ConfigError(f"shards {s.path} and {first.path} differ in format or recorded config; hint: describe "
                              "every shard into the same format")
    count, by_index = first.shard["count"], {}
    for s in shards:
        k = s.shard["index"]
        if k in by_index:
            raise ConfigError(f"shard {k}/{count} is given twice: {by_index[k].path} and {s.path}")
        by_index[k] = s
    if len(by_index) != count:  # indices are below count, so one of the first len + 1 is missing
        missing = [k for k in range(min(count, len(by_index) + 4)) if k not in by_index]
        more = ", ..." if len(missing) + len(by_index) < count else ""
        raise ConfigError(f"shard(s) {', '.join(f'{k}/{count}' for k in missing)}{more} missing: got indices "
                          f"{sorted(by_index)[:20]}, need every k in 0..{count - 1} exactly once")
    return _contiguous([by_index[k] for k in range(count)])


def _contiguous(ordered: list[ShardFile]) -> list[ShardFile]:
    """``ordered`` after checking that their frame ranges tile ``0..images``."""
    end = 0
    for s in ordered:
        a, b = s.shard["frames"]
        if a != end:
            raise ConfigError(f"shard {s.path} covers images {a}..{b} but the previous shards end at {end}: the "
                              "ranges are not contiguous")
        end = b
    if end != ordered[0].shard["images"]:
        raise ConfigError(f"the shards cover images 0..{end} of {ordered[0].shard['images']}")
    return ordered


def merge_shards(paths: Sequence[str | os.PathLike[str]], out: str | os.PathLike[str], overwrite: bool = False) -> Path:
    """Merge shard outputs ``paths`` (any order) into ``out`` (see the module docstring), under ``out``'s lock."""
    out = Path(out)
    if not paths:
        raise ConfigError("describe merge needs the shard files to merge (SHARD...)")
    if out.suffix.lower() not in OUT_SUFFIXES:
        raise ConfigError(f"output file {out} must end in one of {', '.join(OUT_SUFFIXES)}")
    if any(Path(p).resolve() == out.resolve() for p in paths):
        raise ConfigError(f"--out {out} is one of the shards to merge; choose another output")
    with locked(out):
        remove_dead_temps([out, names_file_for(out), provenance_sidecar(out)])
        if out.exists() and not overwrite:
            raise ConfigError(f"output {out} already exists (hint: --overwrite replaces it)")
        check_sidecars(out, overwrite)
        shards = check_shards([read_shard(p) for p in paths])
        config = shards[0].config
        if config is None and out.suffix.lower() != ".npy":
            raise ConfigError(f"the shards are .npy files, which record no describe config; --out {out} must end "
                              "in .npy too")
        n, d = sum(s.shape[0] for s in shards), shards[0].shape[1]
        names = list(itertools.chain.from_iterable(s.names for s in shards))
        write_output(out, (n, d), itertools.chain.from_iterable(s.blocks() for s in shards), names,
                     config or json.dumps({}), shards[0].prov)
    logger.info("merged %d shards (%d descriptors of dim %d) into %s", len(shards), n, d, out)
    return out
