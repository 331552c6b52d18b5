"""The :class:`Describer`: a fitted descriptor function of images, and describing lists of image paths."""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import numpy as np

from ..core.devices import get_device
from ..core.errors import ConfigError, ImageError
from ..core.log import counted, logger
from ..core.memmaps import RowsOut
from ..core.progress import progress
from ..security.pictures import size_mismatch
from .config import DescribeConfig
from .images import ImageItem, ImageRef, as_image, iter_batches, list_images, load_images
from .pca import PCA, fit_pca
from .registry import Extract, FitContext
from .state import StateFile, method_state_file, pca_file
from .views import VIEWS, described_views

Sink = Callable[[np.ndarray, np.ndarray | None], None]


@dataclasses.dataclass
class Describer:
    """A fitted descriptor function: ``describer(images uint8 [B, H, W(, 3)]) → [B, D] float32``.

    Build one with :func:`make_describer`; use :meth:`describe` on image paths and :meth:`load` to
    read images as it does. Reference and query traverses must be described by the same describer
    (same fitted PCA / NetVLAD clusters).

    Attributes:
        config: the settings, ``size`` resolved ("native" or (W, H)).
        extract: the method's raw descriptors ``[B, D0]`` (of the first of the config's views).
        pca: the PCA applied after ``extract`` (``config.dim``), or None.
        seen_size: ``(W, H)`` of the images it last loaded (cropped and resized as described), None before any:
            recorded in the descriptors' provenance (:mod:`seqnet.core.provenance`).
        view_extracts: each view's ``extract`` (its own fitted state), when the config has several views.
    """

    config: DescribeConfig
    extract: Extract
    pca: PCA | None = None
    seen_size: tuple[int, int] | None = None
    view_extracts: dict[str, Extract] | None = None

    @property
    def method(self) -> str:
        """The descriptor method name."""
        return self.config.method

    def __call__(self, images: np.ndarray) -> np.ndarray:
        raw = self.raw(images)
        return raw if self.pca is None else self.pca.transform(raw)

    def raw(self, images: np.ndarray) -> np.ndarray:
        """``[B, D]`` before the PCA: ``extract`` of each of the config's views of ``images``, concatenated
        (:func:`~seqnet.describe.views.described_views`; one view: ``extract`` itself)."""
        extracts = self.view_extracts or {}
        return described_views(images, self.config.views, lambda view, x: extracts.get(view, self.extract)(x))

    def load_some(self, paths: Sequence[str | os.PathLike[str] | ImageItem]) -> tuple[np.ndarray, list[int]]:
        """Images as :meth:`load`, leaving unreadable ones out with ``skip_corrupted``; also their indices."""
        c = self.config
        imgs, skipped = load_images([as_image(p) for p in paths], size=c.image_size, crop_bottom=c.crop_bottom,
                                    grey=c.method_spec.grey, skip_corrupted=c.skip_corrupted)
        self._saw(imgs)
        return imgs, skipped

    def _saw(self, imgs: np.ndarray) -> None:
        """Note the size of images ``[N, H, W(, 3)]`` just loaded (when there are any)."""
        if len(imgs):
            self.seen_size = (int(imgs.shape[2]), int(imgs.shape[1]))

    def load(self, paths: Sequence[str | os.PathLike[str] | ImageItem]) -> np.ndarray:
        """uint8 images ``[N, H, W]`` (grey methods) or ``[N, H, W, 3]`` read, cropped and resized as the
        describer reads them (files, or :class:`~seqnet.describe.images.ImageItem` s such as bag frames); an
        unreadable image raises :class:`ImageError` (rows match ``paths``)."""
        c = self.config
        imgs = load_images([as_image(p) for p in paths], size=c.image_size, crop_bottom=c.crop_bottom,
                           grey=c.method_spec.grey)[0]
        self._saw(imgs)
        return imgs

    def batches(self, paths: Sequence[ImageRef], what: str, view: str | None = None) -> Iterator[np.ndarray]:
        """Image batches of ``paths`` (for fitting), with a progress bar labelled ``what``; ``view``: that
        :data:`~seqnet.describe.views.VIEWS` view of them (a method's state, the NetVLAD clusters, is fitted per
        view)."""
        for b in progress(list(iter_batches(len(paths), self.config.batch_size)), desc=what, unit="batch"):
            imgs, _ = self.load_some([paths[i] for i in b])
            if len(imgs):
                yield imgs if view is None else VIEWS[view](imgs)

    def describe(self, paths: Sequence[str | os.PathLike[str] | ImageItem], names: Sequence[str] | None = None,
                 spill: bool = False) -> tuple[np.ndarray, list[str]]:
        """Descriptors ``[N, D]`` float32 of ``paths`` and their names (default: the file names);
        images skipped with ``skip_corrupted`` are left out of both. ``spill``: descriptors over
        ``SEQNET_SPILL_MB`` go to a temporary file, returned as a read-only
        :class:`~seqnet.core.memmaps.Spilled` map."""
        paths = [as_image(p) for p in paths]
        if not paths:
            raise ImageError("no images to describe (empty list of paths)")
        names = [p.name for p in paths] if names is None else list(names)
        rows = _Rows(len(paths), spill)
        run_batches(paths, self, np.ones(len(paths), bool), rows.sink)
        if not rows.kept:
            raise ImageError(f"none of the {len(paths)} images could be read (first: {paths[0]})")
        return rows.finish(), [names[i] for i in rows.kept]


class _Rows:
    """``[K, D]`` float32 descriptors of the K images described of N, filled batch by batch in image order
    (:func:`run_batches` visits the images in order): an array, or a spill file when ``spill`` and large
    (:class:`~seqnet.core.memmaps.RowsOut`)."""

    def __init__(self, n: int, spill: bool) -> None:
        self.n, self.spill, self.kept = n, spill, []
        self.out: RowsOut | None = None

    def sink(self, idx: np.ndarray, desc: np.ndarray | None) -> None:
        if desc is None:
            return
        if self.out is None:
            self.out = RowsOut((self.n, int(desc.shape[1])), np.float32, self.spill)
        self.out.put(desc)
        self.kept.extend(idx.tolist())

    def finish(self) -> np.ndarray:
        return self.out.finish(short=True)


def make_describer(conf: DescribeConfig, paths: Sequence[str | os.PathLike[str] | ImageItem] = (),
                   sidecar: str | os.PathLike[str] | None = None) -> Describer:
    """Build (and fit, when a PCA or NetVLAD clusters are asked for) a :class:`Describer`.

    Args:
        conf: the settings.
        paths: the images to be described; the fitting images are picked from them when
            ``conf.fit`` is None or an int.
        sidecar: the output file the fitted state belongs to: it is loaded from / saved beside it as
            ``<stem>.pca.npz`` and ``<stem>.netvlad.pth.tar`` (see :mod:`seqnet.describe.state`; a
            file there that this output did not write raises :class:`ConfigError`). None: nothing saved.
    """
    conf = conf.resolved()
    check_view_checkpoint(conf)
    fit_paths = fit_paths_of(conf, [as_image(p) for p in paths]) if conf.needs_fit else []
    pca_state = pca_file(conf, sidecar, fit_paths)
    reuse_pca = pca_state is not None and pca_state.reusable()
    loader = Describer(conf, lambda images: images)
    extracts: dict[str, Extract] = {}
    for view in conf.views:  # a fitted state per view; a method that fits none is built once
        if extracts and not conf.method_spec.fits_state:
            extracts[view] = extracts[conf.views[0]]
            continue
        own = method_state_file(conf, sidecar, fit_paths, view)
        what = f"fitting images ({conf.method}{'' if len(conf.views) == 1 else ', ' + view})"
        ctx = FitContext(device=get_device(conf.device), n_images=len(fit_paths),
                         batches=lambda v=view, w=what: loader.batches(fit_paths, w, v),
                         state=own.path if own else None, reuse=own is not None and own.reusable(),
                         tag=own.tag if own else None, image_size=conf.image_size,
                         view=view if len(conf.views) > 1 else None)
        extracts[view] = conf.method_spec.extractor(ctx)
    d = Describer(conf, extracts[conf.views[0]], view_extracts=extracts if len(extracts) > 1 else None)
    if conf.dim is not None:
        d.pca = _pca_for(d, fit_paths, pca_state, reuse_pca)
    return d


def check_view_checkpoint(conf: DescribeConfig) -> None:
    """Refuse several views with a state fitted by seqnet for one (``--checkpoint`` of a NetVLAD it fitted): each
    view fits its own, so the other views would be described with the first one's clusters (a pretrained
    checkpoint from elsewhere serves every view)."""
    path = getattr(conf.method_spec, "checkpoint", None)
    tag = conf.method_spec.read_tag(Path(path)) if len(conf.views) > 1 and path else None
    if tag is not None:
        raise ConfigError(f"--checkpoint {path} holds the {conf.method} state seqnet fitted for one view, and "
                          f"--views {','.join(conf.views)} fits one per view (hint: drop --checkpoint and pass "
                          f"--fit-on {fitted_on_text(tag)}: the same state is fitted again for each view; or "
                          "describe both traverses in one run, e.g. seqnet dataset from-images ... --views, which "
                          "fits them once for both)")


def fitted_on_text(tag: str) -> str:
    """The images the state of ``tag`` (:func:`.state.state_tag`) was fitted on, as far as the tag says (the output it
    was fitted for, the number of images): ``the 200 images r.h5 was fitted on (their folder or list file)``."""
    try:
        found = json.loads(tag)
    except (ValueError, RecursionError):
        found = None
    found = found if isinstance(found, dict) else {}
    output, fit = found.get("output"), found.get("fit_images")
    n = fit.get("paths") if isinstance(fit, dict) else None
    images = f"the {n} images" if isinstance(n, int) else "the images"
    made = f" {output} was fitted on" if isinstance(output, str) and output else " it was fitted on"
    return f"{images}{made} (their folder or list file)"


def _pca_for(d: Describer, fit_paths: list[ImageRef], state: StateFile | None, reuse: bool) -> PCA:
    """The PCA of ``d``'s raw descriptors: reused from ``state``, or fitted on ``fit_paths`` (and saved)."""
    if state is not None and reuse:
        logger.info("reusing the PCA of %s", state.path)
        return PCA.load(state.path)
    raw = [d.raw(imgs) for imgs in d.batches(fit_paths, "PCA descriptors")]
    x = np.concatenate(raw) if raw else np.zeros((0, 1), np.float32)
    dim = int(d.config.dim or 0)
    logger.info("fitting PCA %d -> %d%s on %d images", x.shape[1], dim, " whitened" * d.config.whiten, len(x))
    pca = fit_pca(x, dim, whiten=d.config.whiten)
    if state is not None:
        pca.save(state.path, tag=state.tag)
    return pca


def fit_paths_of(conf: DescribeConfig, paths: Sequence[ImageRef]) -> list[ImageRef]:
    """Images to fit PCA / NetVLAD clusters on, from ``conf.fit`` (see :class:`DescribeConfig`)."""
    fit = conf.fit
    if fit is None:
        if not paths:
            raise ConfigError("no images to fit PCA / NetVLAD clusters on (hint: pass fit=... / --fit-on)")
        idx = np.unique(np.linspace(0, len(paths) - 1, min(len(paths), conf.fit_max)).round().astype(int))
        return [as_image(paths[i]) for i in idx]
    if isinstance(fit, int):
        return [as_image(p) for p in paths[:fit]]
    if isinstance(fit, str):
        return list_images(fit).paths
    return [as_image(p) for p in fit]


def run_batches(paths: Sequence[ImageRef], d: Describer, todo: np.ndarray, sink: Sink) -> None:
    """Describe ``paths[todo]`` in batches; ``sink(indices [b], descriptors [b, D])`` gets each batch.

    Skipped (corrupted) images reach ``sink`` with descriptors None. Raises :class:`ImageError`
    when native-size images differ in size across batches.
    """
    shape, first = None, None
    n = int(todo.sum())
    bar = progress(total=n, desc=f"describe ({d.method})", unit="img")
    for b in iter_batches(len(paths), d.config.batch_size, todo):
        imgs, skipped = d.load_some([paths[i] for i in b])
        keep = np.delete(b, skipped)
        if skipped:
            bad = ", ".join(str(paths[b[i]]) for i in skipped)
            logger.warning("skipped %s: %s", counted(len(skipped), "unreadable image"), bad)
            sink(b[skipped], None)
        if len(keep):
            if shape is not None and imgs.shape[1:] != shape:
                raise size_mismatch(paths[keep[0]], imgs.shape[1:], first, shape)
            starts = shape is None
            if starts:
                check_batch_memory(d, imgs.shape)
                shape, first = imgs.shape[1:], paths[keep[0]]
            out = d(imgs)
            if starts:
                check_output_memory(n, out.shape[1], d.method)
            sink(keep, out)
        bar.update(len(b))
    bar.close()


def describe_images(paths: Sequence[str | os.PathLike[str] | ImageItem], conf: DescribeConfig,
                    names: Sequence[str] | None = None) -> tuple[np.ndarray, list[str]]:
    """Descriptors ``[N, D]`` float32 (rows L2-normalised) of the images ``paths`` and their names.

    ``names`` default to the file names; images skipped with ``conf.skip_corrupted`` are left out
    of both. PCA / NetVLAD clusters are fitted on ``conf.fit`` (default: up to ``fit_max`` of
    ``paths``); to describe several traverses with one fitted state use :func:`make_describer`.
    """
    return make_describer(conf, paths).describe(paths, names)


def check_batch_memory(d: Describer, shape: tuple[int, ...]) -> None:
    """Refuse, before the first forward pass, a batch of images ``shape [B, H, W(, 3)]`` whose working memory
    (:meth:`seqnet.describe.registry.DescribeMethod.bytes_per_pixel`) cannot fit: one line, exit 1."""
    from ..core.memory import check_fits

    per = d.config.method_spec.bytes_per_pixel()
    check_fits(d.config.batch_size * shape[1] * shape[2] * per,
               f"describing batches of {d.config.batch_size} images of {shape[2]}x{shape[1]} with {d.method}",
               "a smaller --batch-size or --resize")


def check_output_memory(n: int, dim: int, method: str) -> None:
    """Refuse, after the first batch (its D known), ``n`` descriptors of ``dim`` that cannot be held (the
    output is read back whole when written)."""
    from ..core.memory import check_fits

    check_fits(4 * n * dim, f"{n} {method} descriptors of D={dim} (float32)",
               "fewer dimensions (--dim N: PCA), or describe in shards (--shard k/N, then describe merge)")
