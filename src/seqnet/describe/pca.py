"""PCA (optionally whitened) for reducing single-image descriptors; saved as ``.npz``."""

from __future__ import annotations

import dataclasses
import math
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import CheckpointError, ConfigError, SeqnetError
from ..security.arrays import read_npz
from ..security.files import atomic_path
from ..security.jsonfile import read_json_object

TAG_KEY = "seqnet_tag"  # provenance string stored by PCA.save(tag=...)

PAPER_PCA_DIM = 4096  # the SeqNet paper reduces its descriptors (NetVLAD 32768-D) to 4096 with PCA
BLOCK = 4096  # rows projected at a time (PCA.transform_blocks)


@dataclasses.dataclass
class PCA:
    """A fitted PCA projection.

    Attributes:
        mean: ``[D]`` float32 mean of the fitting data.
        components: ``[dims, D]`` float32 principal axes (orthonormal rows, by decreasing variance).
        scales: ``[dims]`` float32 per-component scale (1/sqrt(variance + eps) when whitened, else 1).
        whiten: whether ``scales`` whiten the output.
        l2: whether :meth:`transform` L2-normalises its output by default.
    """

    mean: np.ndarray
    components: np.ndarray
    scales: np.ndarray
    whiten: bool = False
    l2: bool = True

    @property
    def dims(self) -> int:
        """Output dimension."""
        return int(self.components.shape[0])

    @property
    def input_dim(self) -> int:
        """Input dimension D."""
        return int(self.components.shape[1])

    def transform_blocks(self, desc: np.ndarray) -> np.ndarray:
        """``[N, D]`` → ``[N, dims]`` float32 (:meth:`transform`), :data:`BLOCK` rows at a time (a memory map is
        read in blocks)."""
        out = np.empty((len(desc), self.dims), np.float32)
        for a in range(0, len(desc), BLOCK):
            out[a : a + BLOCK] = self.transform(np.asarray(desc[a : a + BLOCK], np.float32))
        return out

    def transform(self, x: np.ndarray, l2: bool | None = None) -> np.ndarray:
        """Project ``[N, D]`` to ``[N, dims]`` float32 (L2-normalised rows when ``l2``, default ``self.l2``)."""
        x = np.asarray(x, dtype=np.float32)
        if x.ndim != 2 or x.shape[1] != self.input_dim:
            raise ConfigError(
                f"PCA expects [N, {self.input_dim}] descriptors, got shape {x.shape} "
                "(hint: the PCA was fitted on descriptors of another method or size)"
            )
        y = ((x - self.mean) @ self.components.T) * self.scales
        if self.l2 if l2 is None else l2:
            y = y / np.maximum(np.linalg.norm(y, axis=1, keepdims=True), 1e-12)
        return y.astype(np.float32)

    def save(self, path: str | os.PathLike[str], tag: str | None = None) -> Path:
        """Write the PCA as ``.npz`` atomically, with an optional provenance ``tag`` (see :func:`read_tag`)."""
        path = Path(path)
        extra = {} if tag is None else {TAG_KEY: np.array(tag)}
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as f:
                np.savez(f, mean=self.mean, components=self.components, scales=self.scales,
                         whiten=np.array(self.whiten), l2=np.array(self.l2), **extra)
        return path

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> PCA:
        """Read a PCA written by :meth:`save`; raise :class:`CheckpointError` when it is not one."""
        keys = ("mean", "components", "scales", "whiten", "l2")
        arrays = read_npz(path, "PCA file", CheckpointError, keys=keys)
        missing = [k for k in keys if k not in arrays]
        if missing:
            raise CheckpointError(f"{path}: not a seqnet PCA file (missing {', '.join(missing)})")
        if arrays["mean"].ndim != 1 or arrays["components"].ndim != 2 or \
                arrays["components"].shape[1] != arrays["mean"].shape[0]:
            raise CheckpointError(f"{path}: a PCA file needs mean [D] and components [D', D], got "
                                  f"{arrays['mean'].shape} and {arrays['components'].shape}")
        return cls(mean=arrays["mean"].astype(np.float32), components=arrays["components"].astype(np.float32),
                   scales=arrays["scales"].astype(np.float32), whiten=bool(arrays["whiten"]), l2=bool(arrays["l2"]))


def read_tag(path: str | os.PathLike[str]) -> str | None:
    """The provenance tag stored by :meth:`PCA.save` in ``path``; None when absent or not a PCA file."""
    try:
        arrays = read_npz(path, "PCA file", CheckpointError, kinds="U", keys=[TAG_KEY])
    except CheckpointError:
        return None
    return str(arrays[TAG_KEY][()]) if TAG_KEY in arrays else None


def dataset_pca_path(dataset_dir: str | os.PathLike[str]) -> Path:
    """Where the train-split PCA of a reduced dataset directory is saved (``--pca D``): ``<DIR>.pca.npz`` beside it."""
    d = Path(dataset_dir)
    return d.with_name(d.name + ".pca.npz")


REDUCED_SUFFIX = re.compile(r"-pca\d+$")  # the suffix of reduced_dataset_path


def reduced_dataset_path(dataset_dir: str | os.PathLike[str], dims: int) -> Path:
    """Where ``seqnet train --pca D`` writes the dataset directory ``dataset_dir`` reduced to ``dims``:
    ``<DIR>-pca<dims>`` beside it."""
    d = Path(dataset_dir)
    return d.with_name(f"{d.name}-pca{dims}")


def unreduced_dataset_path(dataset_dir: str | os.PathLike[str]) -> Path:
    """The directory that :func:`reduced_dataset_path` named ``dataset_dir`` after (``<DIR>`` of
    ``<DIR>-pca<D>``); ``dataset_dir`` itself when its name has no such suffix."""
    d = Path(dataset_dir)
    return d.with_name(REDUCED_SUFFIX.sub("", d.name))



def unreduced_source(dataset_dir: str | os.PathLike[str]) -> Path | None:
    """The dataset directory that a chain of ``seqnet train --pca`` reductions of ``dataset_dir`` started from
    (``<DIR>`` of ``<DIR>-pca<D>[-pca<D'>]``, beside it, each PCA's recorded ``source`` the provenance id of the
    reference descriptors of the one before); None when ``dataset_dir`` records no PCA or its source is not found."""
    path = Path(dataset_dir)
    here = pca_record(path)
    while here is not None and here[0] is not None:
        found = reduced_from(path, here[0])
        if found is None:
            return None
        path, here = found
    return path if here is not None and path != Path(dataset_dir) else None


def reduced_from(dataset_dir: Path, pca: dict) -> tuple[Path, tuple[dict | None, object]] | None:
    """The ``<DIR>`` beside ``dataset_dir`` = ``<DIR>-pca<D>`` whose descriptors its PCA (``pca``: the ``"pca"``
    entry of its dataset.json) reduced, i.e. whose reference provenance id is the PCA's ``source``, with its
    :func:`pca_record`; None otherwise."""
    parent = unreduced_dataset_path(dataset_dir)
    there = pca_record(parent) if parent != dataset_dir else None
    return (parent, there) if there is not None and there[1] == pca.get("source") else None


def pca_record(dataset_dir: Path) -> tuple[dict | None, object] | None:
    """``(the "pca" entry of its dataset.json or None, its reference provenance id)``; None when ``dataset_dir`` is
    not a dataset directory that can be read."""
    try:
        meta = read_json_object(dataset_dir / "dataset.json", "dataset file") if dataset_dir.is_dir() else None
    except (SeqnetError, OSError):
        return None
    if meta is None:
        return None
    prov = meta.get("provenance") if isinstance(meta.get("provenance"), dict) else {}
    ref = prov.get("reference") if isinstance(prov.get("reference"), dict) else {}
    return (meta["pca"] if isinstance(meta.get("pca"), dict) else None), ref.get("id")


def load_dataset_pca(path: str | os.PathLike[str], provenance: dict) -> PCA:
    """The PCA in ``path`` that reduced descriptors of ``provenance`` (``--pca D``: the file's tag is their provenance
    id, its output D theirs); :class:`ConfigError` when it is missing or written for other descriptors,
    :class:`CheckpointError` when it is not a PCA file."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"the map's descriptors were reduced by the PCA in {path} (--pca), which is missing; "
                          "query images can only be described alike with it (hint: keep it beside the dataset "
                          "directory it was written with, or rebuild the dataset)")
    pca = PCA.load(path)
    tag = read_tag(path)
    if tag != provenance.get("id") or pca.dims != provenance.get("dim"):
        raise ConfigError(f"{path} is not the PCA the map's descriptors were reduced with (its tag {tag!r} and "
                          f"{pca.dims} dimensions, the map's provenance {provenance.get('id')!r} and "
                          f"{provenance.get('dim')}); hint: rebuild the dataset with --pca")
    return pca


def spread_frames(part: Any, most: int) -> tuple[np.ndarray, int]:
    """``([n, D] float32, N)``: at most ``most`` of the ``N`` frames of both traverses of ``part`` (a dataset or
    its split), evenly spaced, reference first: the rows a dataset PCA is fitted on."""
    n_r, n_q = len(part.reference), len(part.query)
    rows = np.unique(np.linspace(0, n_r + n_q - 1, min(n_r + n_q, most)).round().astype(np.int64))
    ref, qry = rows[rows < n_r], rows[rows >= n_r] - n_r
    return np.concatenate([np.asarray(part.reference.descriptors[ref], np.float32),
                           np.asarray(part.query.descriptors[qry], np.float32)]), n_r + n_q


def suggested_pca_dims(rows: int, in_dims: int | None = None) -> int:
    """The PCA size every message suggests (the training guide, its memory refusal, a ``--pca`` / ``--dim`` too large
    for its frames): a power of two at most :data:`PAPER_PCA_DIM`, below ``in_dims`` and at most half the ``rows``
    it is fitted on (N rows centred span N - 1 axes; half leaves each axis two frames), at least 1."""
    cap = min(PAPER_PCA_DIM, (rows - 1) // 2, PAPER_PCA_DIM if in_dims is None else in_dims - 1)
    return 2 ** int(math.log2(cap)) if cap >= 1 else 1


def check_fit_rows(dims: int, rows: int, option: str, source: str, more: str, unit: str = "frames") -> None:
    """Raise :class:`ConfigError` when a PCA to ``dims`` cannot be fitted on ``rows`` descriptors: N rows centred on
    their mean span at most N - 1 axes, so ``dims`` must be below ``rows``. The message names the ``option``
    (``--pca``, ``--dim``), where the rows come from (``source``, e.g. "the 'train' split has"), their ``unit`` and
    what gives ``more`` of them."""
    if dims >= rows:
        raise ConfigError(f"{option} {dims}: {source} {rows} {unit}, and a PCA fitted on them has at most "
                          f"{max(0, rows - 1)} axes (N {unit} centred on their mean span N - 1) (hint: {option} "
                          f"{suggested_pca_dims(rows)} or {more})")


def fit_pca(x: np.ndarray, dims: int, whiten: bool = False, l2: bool = True, eps: float = 1e-9) -> PCA:
    """Fit a PCA of ``[N, D]`` data keeping ``dims`` components.

    Args:
        x: ``[N, D]`` training descriptors.
        dims: output dimension, 1 <= dims <= min(N - 1, D) (N centred rows span at most N - 1 axes).
        whiten: scale each component to unit variance.
        l2: default of :meth:`PCA.transform`'s output L2-normalisation.
        eps: added to the variances before whitening.
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2:
        raise ConfigError(f"PCA needs [N, D] data, got shape {x.shape}")
    n, d = x.shape
    check_fit_rows(dims, n, "--dim", "the PCA is fitted on", "more images to fit it on (--fit-on)", "images")
    if not 1 <= dims <= d:
        raise ConfigError(f"--dim {dims}: a PCA of {d}-D descriptors keeps between 1 and {d} dimensions (hint: "
                          f"--dim {min(max(1, dims), d)})")
    mean = x.mean(axis=0)
    xc = x - mean
    if d <= n:
        evals, evecs = np.linalg.eigh(xc.T @ xc / max(n - 1, 1))
        order = np.argsort(evals)[::-1][:dims]
        comps, var = evecs[:, order].T, evals[order]
    else:
        _, s, vt = np.linalg.svd(xc, full_matrices=False)
        comps, var = vt[:dims], (s[:dims] ** 2) / max(n - 1, 1)
    comps = comps * np.where(comps[np.arange(dims), np.abs(comps).argmax(axis=1)] < 0, -1.0, 1.0)[:, None]
    scales = 1.0 / np.sqrt(np.maximum(var, 0.0) + eps) if whiten else np.ones(dims)
    return PCA(mean=mean.astype(np.float32), components=comps.astype(np.float32),
               scales=scales.astype(np.float32), whiten=whiten, l2=l2)
