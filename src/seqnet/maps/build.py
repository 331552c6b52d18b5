"""Building a map from a dataset's reference side and trained models (the ``seqnet index build`` stage)."""

from __future__ import annotations

import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..core.devices import get_device
from ..core.errors import CheckpointError, ConfigError, WindowsTooLongError
from ..core.log import logger
from ..core.memory import check_fits, model_bytes, workspace_bytes
from ..core.tensors import ArrayLike
from ..data.io import load_dataset
from ..data.traverse import Dataset, default_split
from ..describe.pca import PCA, dataset_pca_path, load_dataset_pca
from ..methods.checks import check_models as check_model_inputs
from ..methods.checks import descriptor_dims, model_lengths
from ..reference.traverse import TraverseReference
from ..search.ann import index_bytes, make_index, train_sample_bytes
from ..security.ownership import check_replaceable
from ..sequence.checkpoints import load_models
from ..sequence.descriptors import SEQUENCE_DESCRIPTORS
from ..sequence.windows import Windows
from .chosen import check_given, choose_for_map
from .config import MapConfig
from .edges import edge_frames, edge_rows
from .shards import check_ivf, split_rows
from .store import MapArrays, is_map_file, write_map

if TYPE_CHECKING:
    from ..sequence.model import SeqNet


def resolve(conf: MapConfig, models: Mapping[str, SeqNet]) -> MapConfig:
    """``conf`` with L and L_m resolved once (:meth:`seqnet.sequence.windows.Windows.resolve`)."""
    w = Windows.resolve(conf.seq_len, conf.match_len, conf.window, getattr(models.get("seqnet"), "seq_len", None))
    return conf.merge(seq_len=w.seq_len, match_len=w.match_len)


def check_models(conf: MapConfig, ds: Dataset, models: Mapping[str, SeqNet]) -> None:
    """The models the map's descriptors need are given, read the dataset's D and descriptors, and fit L."""
    missing = conf.roles() - set(models)
    if missing:
        need = " and ".join("an S_1 model (--model S1.pt)" if r == "s1" else "an S_L model (--model SL.pt)"
                            for r in sorted(missing))
        raise ConfigError(f"map {conf.method.name} (shortlist {conf.shortlist}, re-rank {conf.rerank}) needs {need}; "
                          "hint: train them (seqnet train), or build a map that needs no model: --shortlist single "
                          "(or delta) --rerank raw+seqmatch")
    check_model_inputs(models, ds.reference.dim, ds.reference.provenance, f"dataset {ds.name!r}", conf.windows.seq_len,
                 conf.allow_mismatch, use="the map uses")
    w = conf.windows
    if w.longest > len(ds.reference):
        raise WindowsTooLongError(f"L={w.seq_len} / L_m={w.match_len} is longer than the reference traverse "
                          f"({len(ds.reference)} frames)")


def check_index(conf: MapConfig, ds: Dataset, models: Mapping[str, SeqNet]) -> None:
    """The index settings fit the shortlist descriptors (D, number of items), checked before describing."""
    dim = descriptor_dims([conf.shortlist], models, ds.reference.dim)[0]
    n = len(conf.windows.side(len(ds.reference), ds.reference.seq_bounds).items)
    index = make_index(dim, max(n, 1), conf.ann)  # an alias's sizes, or a factory string FAISS accepts
    factory = conf.ann.factory(dim, max(n, 1))
    held = index_bytes(index, n)
    if conf.shards > 1:  # IVF only, at most one shard per item; one training sample, then the shards in flight
        check_ivf(index, factory)
        split_rows(n, conf.shards)
        in_flight = min(conf.shards, os.cpu_count() or 1)  # one thread each, then merged on disk
        held = train_sample_bytes(index, n) + in_flight * index_bytes(index, -(-n // conf.shards), sample=False)
    check_fits(held + model_bytes(models.values()) + workspace_bytes(n, n),
               f"building the {factory!r} index of {n} items (D={dim})",
               "a compressed index (--index ivf-pq, or a factory string such as 'IVF4096,PQ32'), or fewer "
               "dimensions (--dim, PCA, --out-dims)")


def dataset_pca(dataset: str | Path, provenance: dict | None) -> tuple[PCA | None, str | None]:
    """``(pca, problem)``: the train-split PCA (``<DATASET>.pca.npz``) that reduced the dataset's descriptors
    (``--pca D``), copied into the map so that localize and serve reduce query images alike wherever the map is;
    ``(None, None)`` when no PCA reduced them; ``(None, why)`` (with a warning: the map then localises descriptor
    files, not images) when it is missing or foreign (recorded in the map: ``source.pca_not_copied``)."""
    settings = (provenance or {}).get("settings")
    if not isinstance(settings, dict) or settings.get("pca_on") is None:
        return None, None
    try:
        return load_dataset_pca(dataset_pca_path(dataset), provenance or {}), None
    except (ConfigError, CheckpointError) as e:
        logger.warning("the map is written without its dataset's PCA, so it cannot localise query images (only "
                       "descriptor files): %s", e)
        return None, str(e)


def edge_shortlist(conf: MapConfig, ref: TraverseReference) -> ArrayLike | None:
    """``[E, D1]`` the shortlist descriptors of the reference frames that are no item, when the shortlist is a
    single-frame descriptor that the stored frames are not (its k-NN searches every frame:
    :mod:`seqnet.maps.edges`); None otherwise."""
    edges = edge_frames(ref.items, len(ref.positions))
    if not SEQUENCE_DESCRIPTORS[conf.shortlist].single_frame or conf.frames_descriptor == conf.shortlist \
            or not len(edges):
        return None
    return edge_rows(ref.described.frames(conf.shortlist), edges)


def build(conf: MapConfig, dataset: str | Path, out: str | Path, models: Sequence[str | Path] = (),
          settings: Mapping[str, Any] | None = None) -> Path:
    """Describe the reference side of ``conf.split`` of the dataset directory ``dataset`` with the model
    checkpoints ``models`` (S_L and/or S_1, by their stored role) and write the map to ``out``. ``settings``: HVPR
    settings stored in the map as given (``{"top_k": K}``, ``hvpr-fused``'s ``fuse_top_k`` / ``fuse_weight``), the
    others chosen on the val split (:mod:`seqnet.maps.chosen`)."""
    t0 = time.perf_counter()
    settings = check_given(conf.method, settings or {})
    ds = load_dataset(dataset)
    split = default_split(conf.split, ds.splits)
    loaded = load_models(models, seq_len=conf.seq_len)
    conf = resolve(conf.merge(split=split), loaded)
    sub = ds.split(split)
    check_models(conf, sub, loaded)
    check_index(conf, sub, loaded)
    check_replaceable(out, "map", is_map_file)  # before any work
    pca, no_pca = dataset_pca(dataset, ds.reference.provenance)
    dev = get_device(conf.device)
    for model in loaded.values():
        model.to(dev).eval()
    ref = TraverseReference(sub.reference, conf.windows, loaded, dev, name=ds.name)  # the map: a prepared reference
    shortlist, frames = ref.described.items(conf.shortlist), ref.described.frames(conf.frames_descriptor)
    logger.info("described %d reference items / %d frames in %.1f s", len(ref.items), len(sub.reference),
                sum(ref.described.ms.values()) / 1e3)
    arrays = MapArrays(shortlist, frames, ref.items, ref.match_starts, sub.reference.positions, sub.reference.names,
                       sub.reference.seq_bounds, edge_shortlist(conf, ref))
    a, b = ds.splits[split]["reference"] if split != "all" else (0, len(ds.reference))
    info = {"dataset": ds.name, "dataset_path": str(Path(dataset).resolve()), "split": split,
            "reference_range": [int(a), int(b)], "dataset_reference_frames": len(ds.reference), "radius": ds.radius,
            "position_unit": ds.position_unit, "positions_frame": ds.extra.get("positions_frame"),
            "sampling": ds.extra.get("sampling"),
            "explicit_positives": ds.positives is not None, "input_dim": ds.reference.dim,
            "model_seq_len": model_lengths(loaded),
            "describe_seconds": round(time.perf_counter() - t0, 3),
            "selection": choose_for_map(conf, ds, split, loaded, dataset, settings)}  # map.json's "selection"
    if no_pca is not None:  # localize says why the map has no pca.npz (not an older map: this one tried)
        info["pca_not_copied"] = no_pca
    return write_map(out, conf, arrays, loaded, ds.reference.provenance, info, pca)
