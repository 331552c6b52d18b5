"""A dataset's descriptors reduced by a PCA fitted on its train split only (``--pca D``).

``seqnet dataset from-images --pca D`` and ``seqnet train --pca D`` reduce D-dimensional descriptors to
``D'`` before training: a SeqNet layer has D x out x w weights, so a 6400-D descriptor makes 0.5 GB per
checkpoint and overfits a small training split (the SeqNet paper reduces NetVLAD to 4096 with PCA).

The PCA (:func:`seqnet.describe.pca.fit_pca`, L2-normalised output as ``seqnet describe --dim``) is fitted
on the frames of the **train split only** (both traverses' ranges of that split: what training sees;
never the val or test queries, :func:`fit_on_split`), at most :data:`FIT_MAX` of them evenly spaced, and
applied to every frame (:func:`reduce_dataset`). The reduced dataset records it: a new provenance (the
source's settings with ``dim`` and ``pca_on``, its id hashing the source's id and the split's ranges), so a
model trained on it is refused on the unreduced descriptors, and ``extra["pca"]`` (dimensions, split,
source provenance, the PCA file). The projection itself is saved beside the dataset directory as
``<DIR>.pca.npz`` (:meth:`seqnet.describe.pca.PCA.save`, tagged with the reduced provenance id), to
describe further images alike (``seqnet describe --dim``'s sidecar format).

``seqnet train --pca D`` writes the reduced dataset beside the given one, ``<DATASET>-pca<D>`` (reused when
it is already that reduction of that dataset: :func:`main`), and trains on it; evaluate with it.

What the PCA costs is measured when it is written (:func:`reduce_measured`): the model-free methods' val R@1
before and after the very PCA written (:func:`seqnet.train.pca_cost.cost_of`, time bounded), said in one line (a
WARNING when it loses queries, with whether training needs the PCA for memory: :func:`memory_note`; INFO when it
costs nothing) and recorded as ``extra["pca"]["cost"]`` (dataset.json), so eval and the report can show it. It is
never refused: the user asked for it.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ..core.errors import ConfigError
from ..core.log import logger
from ..core.provenance import fit_digest, image_size_of
from ..core.provenance import make as make_provenance
from ..data.io import load_dataset, save_dataset
from ..data.traverse import Dataset, Traverse
from ..describe.pca import (
    PCA,
    check_fit_rows,
    dataset_pca_path,
    fit_pca,
    reduced_dataset_path,
    spread_frames,
    unreduced_source,
)
from ..train.config import TrainConfig
from ..train.pca_cost import PcaCost, cost_of

FIT_MAX = 20000  # frames a PCA is fitted on at most (evenly spaced): [N, D] float64 in memory


def split_frames(ds: Dataset, split: str) -> np.ndarray:
    """``[n, D]`` float32: the frames of both traverses in the split ``split`` (at most :data:`FIT_MAX`, evenly
    spaced). Raises :class:`ConfigError` when the dataset has no such split."""
    if split not in ds.splits:
        have = ", ".join(ds.splits) or "none"
        raise ConfigError(f"--pca fits the PCA on the {split!r} split only (never val or test), but dataset "
                          f"{ds.name!r} has no such split (its splits: {have}); hint: --split {split}=A:B[,C:D] "
                          "when building the dataset, or --train-split NAME")
    return spread_frames(ds.split(split), FIT_MAX)[0]


def check_fit_frames(dims: int, frames: int, split: str = "train") -> None:
    """Raise :class:`ConfigError` when a PCA to ``dims`` cannot be fitted on ``frames`` frames of ``split``: N frames
    centred on their mean span at most N - 1 axes, so ``dims`` must be below ``frames`` (known before anything is
    described: ``seqnet dataset from-images`` checks it first; :func:`seqnet.describe.pca.check_fit_rows`)."""
    check_fit_rows(dims, min(frames, FIT_MAX), "--pca", f"the {split!r} split has", f"a larger {split} split")


def fit_on_split(ds: Dataset, dims: int, split: str = "train") -> PCA:
    """A PCA to ``dims`` dimensions fitted on the frames of ``split`` only (:func:`split_frames`)."""
    frames = split_frames(ds, split)
    if dims >= ds.query.dim:
        raise ConfigError(f"--pca {dims} does not reduce {ds.query.dim}-D descriptors (hint: --pca below "
                          f"{ds.query.dim})")
    check_fit_frames(dims, len(frames), split)
    logger.info("fitting PCA %d -> %d on the %d frames of the %s split", ds.query.dim, dims, len(frames), split)
    return fit_pca(frames, dims)


def reduce_dataset(ds: Dataset, dims: int, split: str = "train") -> tuple[Dataset, PCA]:
    """``ds`` with its descriptors projected by a PCA fitted on ``split`` only, and that PCA; the provenance and
    ``extra["pca"]`` say so (see the module docstring)."""
    pca = fit_on_split(ds, dims, split)
    source = ds.reference.provenance or {}
    rng = ds.ranges(split)
    settings = {**(source.get("settings") or {}), "dim": dims, "pca_on": split}
    fit = fit_digest([str(source.get("id")), split, repr(sorted(rng.items()))])

    def side(t: Traverse) -> Traverse:  # one id; each side keeps the size its images were described at
        prov = make_provenance(source.get("kind") or "external", settings, dim=dims, fit=fit,
                               image_size=image_size_of(t.provenance))
        return dataclasses.replace(t, descriptors=pca.transform_blocks(t.descriptors), provenance=prov)

    before = ds.extra.get("pca") if isinstance(ds.extra.get("pca"), dict) else None  # a chain: said by localize
    chain = {"input_pca": {k: before.get(k) for k in ("dims", "input_dim", "source")}} if before else {}
    extra = {**ds.extra, "pca": {"dims": dims, "input_dim": ds.query.dim, "fit_split": split,
                                 "fit_ranges": {k: list(v) for k, v in rng.items()}, "source": source.get("id"),
                                 **chain}}
    return dataclasses.replace(ds, reference=side(ds.reference), query=side(ds.query), extra=extra), pca


def reduce_measured(ds: Dataset, dims: int, conf: TrainConfig | None = None) -> tuple[Dataset, PCA]:
    """:func:`reduce_dataset` on ``conf.train_split`` (default: :class:`~seqnet.train.TrainConfig`'s), with what
    the PCA costs measured on ``ds`` (:func:`seqnet.train.pca_cost.cost_of`), said (:func:`say_cost`) and recorded
    in ``extra["pca"]["cost"]`` (:func:`cost_record`; absent when it could not be measured)."""
    conf = conf or TrainConfig()
    reduced, pca = reduce_dataset(ds, dims, conf.train_split)
    part = ds.split(conf.train_split)
    total = len(part.reference) + len(part.query)
    cost = cost_of(ds, conf, pca, min(total, FIT_MAX), total)
    if cost is None:
        return reduced, pca
    record = cost_record(cost, memory_note(ds, conf))
    say_cost(record)
    return dataclasses.replace(reduced, extra={**reduced.extra, "pca": {**reduced.extra["pca"], "cost": record}}), pca


def cost_record(cost: PcaCost, memory: str) -> dict:
    """What dataset.json records of ``cost`` (``memory``: :func:`memory_note`): the split, the val R@1 of each
    measured method before and after, the queries, whether it loses any (``lost``) and the line said (``text``)."""
    line = f"--pca {cost.dims} {'keeps' if cost.cheap else 'lowers'} {cost.text()}"
    if not cost.cheap:
        line += f"; hint: drop --pca, or a larger D (below {cost.in_dims})" + (f"; {memory}" if memory else "")
    return {"split": cost.split, "before": cost.before, "after": cost.after, "queries": cost.queries,
            "cut": cost.cut or None, "fitted": cost.fitted, "lost": not cost.cheap, "text": line}


def say_cost(record: dict) -> None:
    """Say the recorded cost (:func:`cost_record`): a WARNING when the PCA loses queries, else INFO."""
    logger.log(30 if record.get("lost") else 20, "%s", record["text"])


def memory_note(ds: Dataset, conf: TrainConfig) -> str:
    """Whether training ``conf`` on ``ds``'s unreduced descriptors needs the PCA for memory here: the training
    guide's estimate (:func:`seqnet.train.memory.train_bytes`, the mining cache in memory) against what the
    process may allocate ("" when that is unknown)."""
    from ..core.memory import available_bytes, human_bytes, rss_bytes
    from ..train.memory import train_bytes

    free, held = available_bytes(), rss_bytes()
    if free is None:
        return ""
    d = ds.query.dim
    n_train = len(ds.split(conf.train_split).query) if conf.train_split in ds.splits else len(ds.query)
    need = held + train_bytes(conf, d, len(ds.reference), len(ds.query), False, n_train)
    said = f"training S_{conf.seq_len} on it: about {human_bytes(need)} of {human_bytes(held + free)} here"
    if need <= (held + free) / 2:
        return f"D={d} needs no PCA for memory here ({said})"
    return f"D={d} may need fewer dimensions for memory ({said})"


def pca_path(dataset_dir: str | Path) -> Path:
    """Where the PCA of a reduced dataset directory is saved: ``<DIR>.pca.npz`` beside it (one convention:
    :func:`seqnet.describe.pca.dataset_pca_path`, which ``seqnet localize`` reads)."""
    return dataset_pca_path(dataset_dir)


def save_reduced(ds: Dataset, pca: PCA, out: str | Path, overwrite: bool = False, quiet: bool = False) -> Path:
    """Write the reduced dataset ``ds`` to ``out`` and its PCA to :func:`pca_path` (tagged with the provenance);
    ``quiet``: as :func:`seqnet.data.io.save_dataset`'s."""
    ds = dataclasses.replace(ds, extra={**ds.extra, "pca": {**ds.extra["pca"], "file": pca_path(out).name}})
    root = save_dataset(ds, out, overwrite=overwrite, quiet=quiet)
    pca.save(pca_path(root), tag=ds.reference.provenance["id"])
    return root


def main(dataset: str | Path, dims: int, split: str = "train", conf: TrainConfig | None = None,
         src: Dataset | None = None) -> Path:
    """``seqnet train --pca D``: the dataset ``dataset`` reduced to ``dims`` by a PCA fitted on ``split``, in
    ``<dataset>-pca<dims>`` beside it (written, its cost measured for training ``conf``: :func:`reduce_measured`;
    or reused when it is that reduction of that dataset, its recorded cost said again). ``src``: ``dataset`` as
    the caller loaded it (not read and hashed again)."""
    conf = (conf or TrainConfig()).merge(train_split=split)
    src = load_dataset(dataset) if src is None else src
    out = reduced_dataset_path(dataset, dims)
    warn_reduced(dataset, src, dims)
    if out.exists():
        made = load_dataset(out).extra.get("pca") or {}
        wanted = {"dims": dims, "fit_split": split, "source": (src.reference.provenance or {}).get("id"),
                  "fit_ranges": {k: list(v) for k, v in src.ranges(split).items()} if split in src.splits else None}
        if any(made.get(k) != v for k, v in wanted.items()):
            raise ConfigError(f"{out} exists but is not {dataset} reduced by --pca {dims} on its {split!r} split "
                              "(hint: remove or rename it)")
        logger.info("reusing %s (%s reduced to %d dimensions by a PCA fitted on its %s split)", out, dataset, dims,
                    split)
        if isinstance(made.get("cost"), dict) and made["cost"].get("text"):
            say_cost(made["cost"])
        return out
    reduced, pca = reduce_measured(src, dims, conf)
    save_reduced(dataclasses.replace(reduced, name=f"{src.name}-pca{dims}"), pca, out)
    logger.info("wrote %s: %s reduced from %d to %d dimensions by a PCA fitted on its %s split only (the "
                "projection: %s); train and evaluate on it", out, dataset, src.query.dim, dims, split, pca_path(out))
    return out


def warn_reduced(dataset: str | Path, src: Dataset, dims: int) -> None:
    """Warn when ``--pca dims`` is asked of a dataset already reduced by a PCA (``from-images --pca`` or ``train
    --pca``): the result is reduced twice, and localize, index build and serve apply one PCA to the images they
    describe, so its map cannot take query images. Names the unreduced dataset when it lies beside
    (:func:`seqnet.describe.pca.unreduced_source`), else the rebuild."""
    before = src.extra.get("pca")
    if not isinstance(before, dict):
        return
    source = unreduced_source(dataset)
    hint = (f"seqnet train --dataset {source} --pca {dims}" if source is not None else "build the dataset with "
            f"seqnet dataset from-images --pca {dims} (or without --pca, then seqnet train --pca {dims} on it)")
    logger.warning("%s is already reduced by a PCA (%s-D to %d-D): --pca %d reduces it a second time, and localize, "
                   "index build and serve apply one PCA to the query images they describe, so its map will not take "
                   "images (descriptor files only); hint: reduce the unreduced descriptors once: %s", dataset,
                   before.get("input_dim", "?"), src.query.dim, dims, hint)

