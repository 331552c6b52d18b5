"""Single-image descriptors of image folders: pixels, GeM, GMP and NetVLAD, with optional PCA.

Library entry points::

    desc, names = describe_images(paths, "gem", size=(256, 128))            # in memory
    desc, names = describe_folder("summer/", "pixels", out="summer.h5")    # resumable file output

Output files: ``.h5``/``.hdf5`` (datasets ``descriptors`` [N, D] float32 and ``names``) or ``.npy``
with the names in a text file beside it (``names.txt`` for ``descriptors.npy``, else
``<stem>.names.txt``) — the formats :func:`seqnet.dataset_io.load_descriptors` reads. Work in progress
lives in a hidden ``.<out>.partial.h5`` with a per-image status mask, so a re-run resumes; fitted
state (PCA, NetVLAD clusters) is saved beside the output as ``<stem>.pca.npz`` and
``<stem>.netvlad.pth.tar``.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from tqdm import tqdm

from ..errors import ConfigError, ImageError
from ..files import atomic_path, save_npy_atomic, write_text_atomic
from ..utils import get_device, logger
from .images import ImageList, iter_batches, list_images, load_images
from .pca import PCA, fit_pca
from .pixels import pixels_descriptor

METHODS = ("pixels", "gem", "gmp", "netvlad")
CNN_SIZE = (640, 320)
AUTO = "auto"


@dataclasses.dataclass
class DescribeOptions:
    """Options of :func:`describe_images` / :func:`describe_folder` (see docs/describe.md).

    ``size`` ``(W, H)`` or None (native) or "auto" (native for pixels, 640×320 for CNN methods);
    ``fit``: images to fit PCA / NetVLAD clusters on: a folder or list file, a list of paths, an
    int N (the first N input images) or None (up to ``fit_max`` input images, evenly spaced).
    """

    size: tuple[int, int] | None | str = AUTO
    crop_bottom: int = 0
    batch_size: int = 8
    device: str | None = AUTO
    patch: int = 8
    backbone: str = "efficientnet-lite0"
    layer: str | int | None = None
    gem_p: float = 3.0
    checkpoint: str | None = None
    use_wpca: bool = True
    clusters: int = 64
    dim: int | None = None
    whiten: bool = False
    fit: Any = None
    fit_max: int = 1000
    skip_corrupted: bool = False
    progress: bool = True
    seed: int = 0

    def resolved_size(self, method: str) -> tuple[int, int] | None:
        if self.size == AUTO:
            return None if method == "pixels" else CNN_SIZE
        return None if self.size is None else (int(self.size[0]), int(self.size[1]))


def make_options(method: str, **options: Any) -> DescribeOptions:
    """Check ``method`` and option names/values; return :class:`DescribeOptions`."""
    if method not in METHODS:
        raise ConfigError(f"unknown descriptor method {method!r}; valid: {', '.join(METHODS)}")
    valid = [f.name for f in dataclasses.fields(DescribeOptions)]
    bad = [k for k in options if k not in valid]
    if bad:
        raise ConfigError(f"unknown describe option {bad[0]!r}; valid: {', '.join(valid)}")
    opts = DescribeOptions(**{k: v for k, v in options.items() if v is not None or k in ("size", "dim", "layer")})
    if opts.batch_size < 1 or opts.crop_bottom < 0:
        raise ConfigError(f"batch size must be >= 1 and crop-bottom >= 0, got {opts.batch_size} and {opts.crop_bottom}")
    if opts.dim is not None and opts.dim < 1:
        raise ConfigError(f"output dim must be >= 1, got {opts.dim}")
    if opts.gem_p <= 0:
        raise ConfigError(f"GeM power p must be > 0, got {opts.gem_p}")
    return opts


def config_of(method: str, opts: DescribeOptions) -> dict[str, Any]:
    """The settings that determine the descriptors (stored with partial outputs to check resumes)."""
    keys = ["crop_bottom", "dim", "whiten", "seed"]
    keys += ["patch"] if method == "pixels" else ["backbone", "layer", "checkpoint", "use_wpca"]
    keys += ["gem_p"] if method == "gem" else ["clusters"] if method == "netvlad" else []
    cfg = {"method": method, "size": opts.resolved_size(method), **{k: getattr(opts, k) for k in keys}}
    cfg["fit"] = opts.fit if isinstance(opts.fit, (int, str, type(None))) else [str(p) for p in opts.fit]
    return json.loads(json.dumps(cfg, default=str))


# ----------------------------------------------------------------------------- describers

Extract = Callable[[np.ndarray], np.ndarray]


@dataclasses.dataclass
class Describer:
    """A fitted descriptor function: ``describer(images uint8 [B, H, W(, 3)]) → [B, D] float32``.

    Build one with :func:`make_describer`; use :meth:`describe` on image paths. Reference and query
    traverses must be described by the same describer (same fitted PCA / NetVLAD clusters).
    """

    method: str
    opts: DescribeOptions
    extract: Extract
    pca: PCA | None = None

    def __call__(self, images: np.ndarray) -> np.ndarray:
        raw = self.extract(images)
        return raw if self.pca is None else self.pca.transform(raw)

    def describe(self, paths: Sequence[str | Path], names: Sequence[str] | None = None) -> tuple[np.ndarray, list[str]]:
        """Descriptors ``[N, D]`` of ``paths`` and their names (skipped corrupted images left out of both)."""
        paths = [Path(p) for p in paths]
        if not paths:
            raise ImageError("no images to describe (empty list of paths)")
        names = [p.name for p in paths] if names is None else list(names)
        rows: dict[int, np.ndarray] = {}

        def sink(idx: np.ndarray, desc: np.ndarray | None) -> None:
            if desc is not None:
                rows.update(zip(idx.tolist(), desc, strict=True))

        run_batches(paths, self, np.ones(len(paths), bool), sink)
        if not rows:
            raise ImageError(f"none of the {len(paths)} images could be read (first: {paths[0]})")
        order = sorted(rows)
        return np.stack([rows[i] for i in order]).astype(np.float32), [names[i] for i in order]


def make_describer(method: str, paths: Sequence[str | Path] = (), sidecar: Path | None = None,
                   **options: Any) -> Describer:
    """Build (and fit, when PCA or NetVLAD clusters are asked for) a :class:`Describer`.

    Args:
        method: one of :data:`METHODS`.
        paths: the images to be described; used to pick fitting images when ``fit`` is None or an int.
        sidecar: output path without suffix: fitted state is loaded from / saved to
            ``<sidecar>.pca.npz`` and ``<sidecar>.netvlad.pth.tar`` (resumable runs).
        options: see :class:`DescribeOptions`.
    """
    opts = make_options(method, **options)
    needs_fit = opts.dim is not None or (method == "netvlad" and not opts.checkpoint)
    fit_paths = fit_paths_of(opts, [Path(p) for p in paths]) if needs_fit else []
    extract = _raw_extractor(method, opts, fit_paths, sidecar)
    d = Describer(method, opts, extract)
    if opts.dim is None:
        return d
    pca_file = sidecar.with_name(sidecar.name + ".pca.npz") if sidecar is not None else None
    if pca_file is not None and pca_file.is_file():
        logger.info("resuming with the PCA of %s", pca_file)
        d.pca = PCA.load(pca_file)
    else:
        raw = [extract(imgs) for imgs in _image_batches(fit_paths, d, "PCA descriptors")]
        x = np.concatenate(raw) if raw else np.zeros((0, 1), np.float32)
        logger.info("fitting PCA %d -> %d%s on %d images", x.shape[1], opts.dim, " whitened" * opts.whiten, len(x))
        d.pca = fit_pca(x, opts.dim, whiten=opts.whiten)
        if pca_file is not None:
            d.pca.save(pca_file)
    return d


def _raw_extractor(method: str, opts: DescribeOptions, fit_paths: list[Path], sidecar: Path | None) -> Extract:
    if method == "pixels":
        return lambda imgs: pixels_descriptor(imgs, size=None, patch=opts.patch)
    from . import cnn as backbones
    from . import netvlad as netvlad

    device = get_device(None if opts.device == AUTO else opts.device)
    if method == "netvlad":
        cache = sidecar.with_name(sidecar.name + ".netvlad.pth.tar") if sidecar is not None else None
        probe = Describer(method, opts, lambda x: x)
        model = netvlad.netvlad_for(
            opts.checkpoint, opts.use_wpca, cache, opts.backbone, opts.layer, opts.clusters, opts.seed, device,
            fit_batches=lambda: _image_batches(fit_paths, probe, "NetVLAD k-means features"), n_fit=len(fit_paths))
        return backbones.cnn_extractor(model, lambda v: v, device)
    encoder = backbones.encoder_for(opts.backbone, opts.layer, opts.checkpoint)
    p = opts.gem_p
    head = (lambda f: backbones.gem(f, p=p)) if method == "gem" else backbones.gmp
    return backbones.cnn_extractor(encoder, head, device)


def _load(d: Describer, paths: Sequence[Path]) -> tuple[np.ndarray, list[int]]:
    return load_images(paths, size=d.opts.resolved_size(d.method), crop_bottom=d.opts.crop_bottom,
                       grey=d.method == "pixels", skip_corrupted=d.opts.skip_corrupted)


def _image_batches(paths: Sequence[Path], d: Describer, what: str) -> Iterator[np.ndarray]:
    for b in tqdm(list(iter_batches(len(paths), d.opts.batch_size)), desc=what, unit="batch",
                  disable=not d.opts.progress):
        imgs, _ = _load(d, [paths[i] for i in b])
        if len(imgs):
            yield imgs


def fit_paths_of(opts: DescribeOptions, paths: Sequence[Path]) -> list[Path]:
    """Images to fit PCA / NetVLAD clusters on, from ``opts.fit`` (see :class:`DescribeOptions`)."""
    fit = opts.fit
    if fit is None:
        if not paths:
            raise ConfigError("no images to fit PCA / NetVLAD clusters on (hint: pass fit=... / --fit-on)")
        idx = np.unique(np.linspace(0, len(paths) - 1, min(len(paths), opts.fit_max)).round().astype(int))
        return [Path(paths[i]) for i in idx]
    if isinstance(fit, int) and not isinstance(fit, bool):
        if fit < 1:
            raise ConfigError(f"fit on the first N images needs N >= 1, got {fit}")
        return [Path(p) for p in paths[:fit]]
    if isinstance(fit, (str, Path)):
        return list_images(fit).paths
    return [Path(p) for p in fit]


def run_batches(paths: Sequence[Path], d: Describer, todo: np.ndarray,
                sink: Callable[[np.ndarray, np.ndarray | None], None]) -> None:
    """Describe ``paths[todo]`` in batches; ``sink(indices, descriptors)`` gets each batch.

    Skipped (corrupted) images reach ``sink`` with descriptors None. Raises :class:`ImageError`
    when native-size images differ in size across batches.
    """
    shape = None
    bar = tqdm(total=int(todo.sum()), desc=f"describe ({d.method})", unit="img", disable=not d.opts.progress)
    for b in iter_batches(len(paths), d.opts.batch_size, todo):
        imgs, skipped = _load(d, [paths[i] for i in b])
        keep = np.delete(b, skipped)
        if skipped:
            bad = ", ".join(str(paths[b[i]]) for i in skipped)
            logger.warning("skipped %d unreadable image(s): %s", len(skipped), bad)
            sink(b[skipped], None)
        if len(keep):
            if shape is not None and imgs.shape[1:] != shape:
                raise ImageError(f"image {paths[keep[0]]} has size {imgs.shape[2]}x{imgs.shape[1]} but earlier images "
                                 f"have {shape[1]}x{shape[0]} (hint: pass a resize size, e.g. --resize 64x32)")
            shape = imgs.shape[1:]
            sink(keep, d(imgs))
        bar.update(len(b))
    bar.close()


def describe_images(paths: Sequence[str | Path], method: str, names: Sequence[str] | None = None,
                    **options: Any) -> tuple[np.ndarray, list[str]]:
    """Descriptors ``[N, D]`` float32 (rows L2-normalised) of the images ``paths`` and their names.

    ``names`` default to the file names; images skipped with ``skip_corrupted=True`` are left out
    of both. PCA / NetVLAD clusters are fitted on ``fit`` (default: up to ``fit_max`` of ``paths``);
    to describe several traverses with one fitted state use :func:`make_describer`. Options: see
    :class:`DescribeOptions`.
    """
    return make_describer(method, paths, **options).describe(paths, names)


def describe_folder(source: str | Path, method: str, out: str | Path | None = None, overwrite: bool = False,
                    **options: Any) -> tuple[np.ndarray, list[str]]:
    """Describe a folder or list file of images; with ``out``, write it resumably (see module doc)."""
    images = list_images(source)
    if out is None:
        return describe_images(images.paths, method, names=images.names, **options)
    return describe_to_file(images, method, Path(out), make_options(method, **options), overwrite)


# ----------------------------------------------------------------------------- resumable file output


def names_file_for(out: Path) -> Path:
    """The names text file written beside a ``.npy`` output."""
    return out.with_name("names.txt") if out.name == "descriptors.npy" else out.with_name(out.stem + ".names.txt")


def describe_to_file(images: ImageList, method: str, out: Path, opts: DescribeOptions,
                     overwrite: bool = False) -> tuple[np.ndarray, list[str]]:
    """Describe ``images`` into ``out`` (.h5/.hdf5/.npy), resuming a partial run with the same settings."""
    if out.suffix.lower() not in OUT_SUFFIXES:
        raise ConfigError(f"output file {out} must end in one of {', '.join(OUT_SUFFIXES)}")
    if out.exists() and not overwrite:
        raise ConfigError(f"output {out} already exists (hint: --overwrite recomputes it)")
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = out.with_name(f".{out.name}.partial.h5")
    sidecar = out.with_suffix("")
    fitted = [sidecar.with_name(sidecar.name + s) for s in (".pca.npz", ".netvlad.pth.tar")]
    config = json.dumps(config_of(method, opts), sort_keys=True)
    if partial.exists() and (overwrite or not _resumable(partial, config, images.names, fitted, method, opts)):
        partial.unlink()
    if not partial.exists():
        for f in fitted:
            f.unlink(missing_ok=True)
    describer = make_describer(method, images.paths, sidecar, **dataclasses.asdict(opts))
    with h5py.File(partial, "a") as h:
        if "status" not in h:
            h.attrs["config"] = config
            h.create_dataset("names", data=np.array(images.names, dtype=object), dtype=h5py.string_dtype())
            h.create_dataset("status", data=np.zeros(len(images), np.int8))
        status = h["status"][()]
        if (status != 0).any():
            logger.info("resuming %s: %d of %d images already done", out, int((status != 0).sum()), len(status))
        run_batches(images.paths, describer, status == 0, _h5_sink(h, len(images)))
        status = h["status"][()]
        keep = np.flatnonzero(status == 1)
        desc = h["descriptors"][()][keep] if "descriptors" in h else np.zeros((0, 0), np.float32)
    if not len(keep):
        raise ImageError(f"none of the {len(images)} images could be read (first: {images.paths[0]})")
    names = [images.names[i] for i in keep]
    _write_output(out, desc, names, config)
    partial.unlink()
    logger.info("wrote %s: %d descriptors of dim %d (%d skipped)", out, len(keep), desc.shape[1],
                len(images) - len(keep))
    return desc, names


OUT_SUFFIXES = (".h5", ".hdf5", ".npy")


def _resumable(partial: Path, config: str, names: list[str], fitted: list[Path], method: str,
               opts: DescribeOptions) -> bool:
    try:
        with h5py.File(partial, "r") as h:
            stored = [n.decode() if isinstance(n, bytes) else n for n in h["names"][()]]
            same = h.attrs.get("config") == config and stored == names
    except (OSError, KeyError):
        logger.warning("partial output %s is unreadable; starting again", partial)
        return False
    if not same:
        raise ConfigError(f"partial output {partial} was made with other settings or images "
                          "(hint: re-run with the same options, or pass --overwrite to start again)")
    needed = [fitted[0]] * (opts.dim is not None) + [fitted[1]] * (method == "netvlad" and not opts.checkpoint)
    missing = [f for f in needed if not f.is_file()]
    if missing:
        logger.warning("fitted state %s is missing; starting %s again", missing[0], partial)
    return not missing


def _h5_sink(h: h5py.File, n: int) -> Callable[[np.ndarray, np.ndarray | None], None]:
    def sink(idx: np.ndarray, desc: np.ndarray | None) -> None:
        if desc is not None:
            if "descriptors" not in h:
                h.create_dataset("descriptors", shape=(n, desc.shape[1]), dtype=np.float32,
                                 chunks=(min(n, 256), desc.shape[1]))
            h["descriptors"][np.sort(idx)] = desc[np.argsort(idx)]
        h["status"][np.sort(idx)] = 1 if desc is not None else 2
        h.flush()

    return sink


def _write_output(out: Path, desc: np.ndarray, names: list[str], config: str) -> None:
    desc = np.ascontiguousarray(desc, dtype=np.float32)
    if out.suffix.lower() == ".npy":
        save_npy_atomic(out, desc)
        write_text_atomic(names_file_for(out), "\n".join(names) + "\n")
        return
    with atomic_path(out) as tmp:
        with h5py.File(tmp, "w") as h:
            h.create_dataset("descriptors", data=desc)
            h.create_dataset("names", data=np.array(names, dtype=object), dtype=h5py.string_dtype())
            h.attrs["config"] = config
