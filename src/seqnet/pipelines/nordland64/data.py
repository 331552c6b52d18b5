"""Nordland64 data: the places, their descriptors (cached), and the training set built from them."""

from __future__ import annotations

import hashlib
import json
import re
import time
from pathlib import Path
from typing import Any

import numpy as np

from ...core.errors import ConfigError, DatasetError
from ...core.log import logger
from ...core.progress import progress
from ...data.io import load_dataset, save_dataset
from ...data.readers import read_names
from ...data.traverse import Dataset, Traverse
from ...describe import Describer, make_describer
from ...describe.images import iter_batches
from ...describe.pca import PCA
from ...describe.stage import describe_provenance
from ...security.arrays import read_npy
from ...security.files import save_npy_atomic
from ...security.locks import locked
from ...security.text import shown
from . import cache
from .config import Nordland64Config

SEASONS = ("summer", "winter")
FRAME_NUMBER = re.compile(r"([0-9]+)")  # ASCII digits only (int() takes others)
SPLITS = ("train", "val", "test")


def list_places(data: str | Path, names_file: str = "nordland_clean_imageNames.txt") -> tuple[list[str], np.ndarray]:
    """Image names in the clean list present in both seasons, by frame number, and positions ``[N]`` (frame/10)."""
    root = Path(data)
    for sub in (*SEASONS, names_file):
        if not (root / sub).exists():
            raise DatasetError(f"{shown(root)} is not the nordland64 data: {sub} is missing "
                               f"(expected {', '.join(SEASONS)}/ and {names_file}; see docs/benchmark_nordland64.md)")
    clean = set(read_names(root / names_file))
    present = {p.name for p in (root / SEASONS[0]).iterdir()} & {p.name for p in (root / SEASONS[1]).iterdir()}
    frames = {n: frame_number(n, root / names_file) for n in clean & present}
    names = sorted(frames, key=lambda n: (frames[n], n))
    if not names:
        raise DatasetError(f"{shown(root)}: no image of {names_file} is present in both {SEASONS[0]}/ and "
                           f"{SEASONS[1]}/")
    return names, np.array([frames[n] / 10.0 for n in names])


def frame_number(name: str, where: Path) -> int:
    """The frame number of a nordland64 image name: its last run of digits (``images-00210.png`` -> 210)."""
    digits = FRAME_NUMBER.findall(name)
    if not digits or len(digits[-1]) > 12:
        raise DatasetError(f"{shown(where)}: the image name '{shown(name)}' has no frame number (expected names "
                           "like images-00210.png, whose last run of digits, at most 12, is the frame number)")
    return int(digits[-1])


def describe_key(conf: Nordland64Config) -> dict[str, Any]:
    """The settings that determine the single-image descriptors (the cache key)."""
    return json.loads(json.dumps({"describe": conf.describe.to_dict(), "fit_range": list(conf.train_range),
                                  "flip_train": conf.flip}))


def describe_seasons(data: Path, names: list[str], conf: Nordland64Config, offset: int = 0) -> dict[str, Any]:
    """Descriptors ``[N, D]`` of the summer (reference) and winter (query) images of ``names``, and
    with ``conf.flip`` of the horizontally flipped train images (``summer_flip``, ``winter_flip``).

    Anything fitted (NetVLAD clusters, PCA of the describer) is fitted on the train range only
    (``names[i]`` is place ``offset + i``). ``"provenance"`` holds how they were made.
    """
    a, b = conf.train_range
    train_names = names[a - offset : b - offset]
    fit = [data / s / n for s in SEASONS for n in train_names]  # the train images of both seasons
    describer = make_describer(conf.describe.merge(fit=fit), fit)
    out: dict[str, Any] = {}
    for season in SEASONS:
        logger.info("describing %d %s images (%s)", len(names), season, conf.describe.label)
        desc, got = describer.describe([data / season / n for n in names], names)
        if len(got) != len(names):
            raise DatasetError(f"{len(names) - len(got)} {season} images could not be read")
        out[season] = desc
        if conf.flip:
            out[f"{season}_flip"] = describe_flipped(describer, [data / season / n for n in train_names])
    out["provenance"] = describe_provenance(describer.config, fit if conf.describe.needs_fit else None, out["summer"])
    return out


def describe_flipped(describer: Describer, paths: list[Path], batch: int = 256) -> np.ndarray:
    """Descriptors ``[N, D]`` of the images ``paths`` mirrored left-right (training augmentation)."""
    out = []
    for idx in progress(list(iter_batches(len(paths), batch)), desc="describe flipped", unit="batch"):
        imgs = describer.load([paths[i] for i in idx])  # size, crop, grey/RGB as the describer reads them
        out.append(describer(np.ascontiguousarray(imgs[:, :, ::-1])))
    return np.concatenate(out).astype(np.float32)


def split_ranges(conf: Nordland64Config, n: int) -> tuple[int, dict[str, dict[str, tuple[int, int]]]]:
    """The first place used and the splits relative to it (only the places in use are described)."""
    ranges = {}
    for split in SPLITS:
        a, b = getattr(conf, f"{split}_range")
        if not 0 <= a < b <= n:
            raise ConfigError(f"--{split}-range {a}:{b} is outside 0:{n} (the {n} nordland64 places) or empty")
        ranges[split] = (a, b)
    lo = min(a for a, _ in ranges.values())
    return lo, {k: {"reference": (a - lo, b - lo), "query": (a - lo, b - lo)} for k, (a, b) in ranges.items()}


def build_dataset(data: str | Path, conf: Nordland64Config, out: Path,
                  overwrite: bool = False) -> tuple[Dataset, np.ndarray | None]:
    """The nordland64 dataset (raw descriptors, places in use, splits), cached in ``out/dataset``, and
    the flipped train descriptors ``[2, n_train, D]`` (summer, winter; cached in ``out/flip_train.npy``;
    None without ``conf.flip``). The two are one cache unit (:mod:`.cache`): reused only together, as
    written by one run with these settings; ``overwrite`` replaces a dataset this cache did not make."""
    data, out = Path(data), Path(out)
    names, pos = list_places(data, conf.names_file)
    lo, splits = split_ranges(conf, len(names))
    hi = lo + max(r["query"][1] for r in splits.values())
    names, pos = names[lo:hi], pos[lo:hi]
    key, flip_file = descriptors_key(conf, data, names), out / "flip_train.npy"
    with locked(out):
        if cache.unit(out, "descriptors", key) is not None:
            logger.info("using cached descriptors in %s", shown(out / "dataset"))
            ds = load_dataset(out / "dataset", mmap=False)
            ds.splits = splits
            return ds, read_npy(flip_file, False) if conf.flip else None
        cache.open_unit(out, "descriptors", cache.DESCRIPTORS, overwrite)  # its key removed first
        ds, flipped = make_dataset(data, conf, names, pos, lo, splits)
        save_dataset(ds, out / "dataset", overwrite=True)
        if flipped is not None:
            save_npy_atomic(flip_file, flipped)
        cache.seal(out, "descriptors", key, cache.files_under(out, "dataset") + ["flip_train.npy"] * conf.flip)
    return ds, flipped


def make_dataset(data: Path, conf: Nordland64Config, names: list[str], pos: np.ndarray, lo: int,
                 splits: dict[str, Any]) -> tuple[Dataset, np.ndarray | None]:
    """Describe the places ``names`` (place ``lo`` first): the dataset and the flipped train descriptors."""
    t0 = time.perf_counter()
    d = describe_seasons(data, names, conf, lo)
    prov = d["provenance"]
    ds = Dataset(reference=Traverse(d["summer"], pos, names=names, name="summer", provenance=prov),
                 query=Traverse(d["winter"], pos, names=list(names), name="winter", provenance=prov),
                 radius=conf.radius,
                 position_unit="frames", splits=splits, name="nordland64",
                 extra={"pos_radius": conf.pos_radius, "neg_radius": conf.neg_radius, "describe": describe_key(conf),
                        "describe_seconds": round(time.perf_counter() - t0, 2), "source": str(data),
                        "first_place": lo})
    return ds, np.stack([d["summer_flip"], d["winter_flip"]]) if conf.flip else None


def descriptors_key(conf: Nordland64Config, data: Path, names: list[str]) -> str:
    """The key of the cached descriptors: their settings, the data folder and the places in use."""
    blob = json.dumps({"describe": describe_key(conf), "source": str(data.resolve()), "names": names})
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def training_dataset(ds: Dataset, pca: PCA | None, symmetric: bool, flipped: np.ndarray | None = None) -> Dataset:
    """The train + val splits of ``ds`` (descriptors PCA-projected) for :func:`seqnet.train.train`.

    With ``symmetric``, the train range is used both ways (winter → summer and summer → winter);
    ``flipped`` ``[2, n_train, D]`` (summer, winter descriptors of the mirrored train images) adds
    the mirrored route. Each is its own sequence, far from the others in position; the val split
    stays winter → summer.
    """
    (a, b), (c, d) = ds.splits["train"]["query"], ds.splits["val"]["query"]

    def proj(x: np.ndarray) -> np.ndarray:
        return np.asarray(x, dtype=np.float32) if pca is None else pca.transform(x, l2=False)

    r, q, p = proj(ds.reference.descriptors), proj(ds.query.descriptors), ds.reference.positions[:, 0]
    pairs = [(r[a:b], q[a:b])] + ([(proj(flipped[0]), proj(flipped[1]))] if flipped is not None else [])
    pairs += [(y, x) for x, y in pairs] if symmetric else []
    gap = 10 * float(p.max()) + 100  # positions of different sequences never within a radius
    parts = [(x, y, p[a:b] + i * gap) for i, (x, y) in enumerate(pairs)] + [(r[c:d], q[c:d], p[c:d])]
    sizes = np.cumsum([0] + [len(x[0]) for x in parts])
    bounds = np.concatenate([np.tile([[s, e]], (e - s, 1)) for s, e in zip(sizes[:-1], sizes[1:], strict=True)])
    ref = Traverse(np.concatenate([x[0] for x in parts]), np.concatenate([x[2] for x in parts]), seq_bounds=bounds)
    qry = Traverse(np.concatenate([x[1] for x in parts]), np.concatenate([x[2] for x in parts]), seq_bounds=bounds)
    n_train, n_all = int(sizes[-2]), int(sizes[-1])
    splits = {"train": {"reference": (0, n_train), "query": (0, n_train)},
              "val": {"reference": (n_train, n_all), "query": (n_train, n_all)}}
    return Dataset(ref, qry, radius=ds.radius, position_unit="frames", splits=splits, name="nordland64-train",
                   extra={"pos_radius": ds.extra["pos_radius"], "neg_radius": ds.extra["neg_radius"]})
