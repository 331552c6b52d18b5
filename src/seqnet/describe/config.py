""":class:`DescribeConfig`: the validated settings of ``seqnet describe`` and :mod:`seqnet.describe`."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import numbers
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..core.config import Config, check_bool, check_choice, check_float, check_int
from ..core.devices import check_device
from ..core.errors import ConfigError
from ..core.provenance import views_text
from .cnn import BACKBONES
from .images import MAX_SIDE, ImageItem
from .registry import DESCRIBERS, DescribeMethod
from .views import DEFAULT_VIEWS, check_views

AUTO, NATIVE, KEEP_ASPECT = "auto", "native", "keep-aspect:"
Size = str | tuple[int, int]  # "auto", "native", "keep-aspect:W" or (W, H)
Fit = int | str | tuple[Any, ...] | None  # a tuple of image paths (str) or ImageItems


@dataclasses.dataclass(frozen=True)
class DescribeConfig(Config):
    """Settings of the describe stage (see docs/describe.md).

    Attributes:
        method: a key of :data:`~seqnet.describe.registry.DESCRIBERS` (pixels, gem, gmp, netvlad).
        size: ``"auto"`` (the method's default: native for pixels, 640×320 for the CNN methods, the
            size a NetVLAD checkpoint written by seqnet was fitted at), ``"native"`` (no resizing; all
            images must then have one size), ``"keep-aspect:W"`` (width W, the height that keeps each
            image's aspect ratio) or ``(W, H)`` (also ``"WxH"``).
        crop_bottom: rows removed from the bottom of each image before resizing.
        batch_size: images per batch.
        device: torch device (auto: CUDA when present).
        patch: pixels: patch-normalisation size (0 or 1: off).
        backbone: a key of :data:`~seqnet.describe.cnn.BACKBONES`.
        layer: backbone feature layer (None: the backbone's default for the method).
        gem_p: gem: pooling power p.
        checkpoint: NetVLAD checkpoint (netvlad; gem/gmp pool its encoder).
        describer: ``package.module:factory`` of your own torch module (method ``plugin``).
        use_wpca: netvlad: apply the checkpoint's WPCA layer.
        clusters: netvlad: clusters K when fitted.
        dim: PCA output dimension (None: no PCA).
        whiten: whiten the PCA output.
        fit: images to fit PCA / NetVLAD clusters on: a folder or list file, a list of paths, an int N
            (the first N input images) or None (up to ``fit_max`` input images, evenly spaced).
        fit_max: the size of the default fitting set.
        skip_corrupted: leave unreadable images out instead of failing.
        seed: random seed of the NetVLAD k-means.
        views: the photometric views each image is described in (:data:`~seqnet.describe.views.VIEWS`, e.g.
            ``("raw", "equalize")``): their descriptors concatenated, D times the views (:mod:`.views`).
    """

    method: str = "pixels"
    size: Size = AUTO
    crop_bottom: int = 0
    batch_size: int = 8
    device: str = AUTO
    patch: int = 8
    backbone: str = "efficientnet-lite0"
    layer: str | int | None = None
    gem_p: float = 3.0
    checkpoint: str | None = None
    describer: str | None = None
    use_wpca: bool = True
    clusters: int = 64
    dim: int | None = None
    whiten: bool = False
    fit: Fit = None
    fit_max: int = 1000
    skip_corrupted: bool = False
    seed: int = 0
    views: tuple[str, ...] = DEFAULT_VIEWS

    def __post_init__(self) -> None:
        check_choice("descriptor method", self.method, DESCRIBERS)
        self._set("size", check_size(self.size))
        for key, low in (("crop_bottom", 0), ("batch_size", 1), ("patch", 0), ("clusters", 1), ("fit_max", 1),
                         ("seed", 0)):
            self._set(key, check_int(key.replace("_", "-"), getattr(self, key), low))
        if self.dim is not None:
            self._set("dim", check_int("output dim", self.dim, 1))
        self._set("gem_p", check_float("GeM power p", self.gem_p, 0.0, strict=True))
        for key in ("use_wpca", "whiten", "skip_corrupted"):
            self._set(key, check_bool(key.replace("_", "-"), getattr(self, key)))
        check_choice("backbone", self.backbone, BACKBONES)
        self._set("layer", BACKBONES[self.backbone].check_layer(self.layer))
        if self.checkpoint is not None:
            self._set("checkpoint", os.fspath(self.checkpoint))
        if self.describer is not None and not DESCRIBERS[self.method].takes_describer:
            takes = [n for n, m in DESCRIBERS.items() if m.takes_describer]
            raise ConfigError(f"--describer goes with --method {' / '.join(takes)}, not {self.method!r}")
        self._set("fit", check_fit(self.fit))
        self._set("views", check_views(self.views))
        check_device(self.device)  # validates the device name
        DESCRIBERS[self.method].of(self)  # the method checks its own settings

    @property
    def method_spec(self) -> DescribeMethod:
        """The :data:`~seqnet.describe.registry.DESCRIBERS` entry with its settings from this config."""
        return DESCRIBERS[self.method].of(self)

    @property
    def image_size(self) -> tuple[int, int] | int | None:
        """``(W, H)`` images are resized to; an int W: width W keeping the aspect ratio; None: native size."""
        if self.size == AUTO:
            return self.method_spec.auto_size()
        if isinstance(self.size, str) and self.size.startswith(KEEP_ASPECT):
            return int(self.size[len(KEEP_ASPECT):])
        return None if self.size == NATIVE else self.size  # type: ignore[return-value]

    def resolved(self) -> DescribeConfig:
        """This config with ``size`` "auto" replaced by what it means for the method ("native" or (W, H))."""
        size = self.image_size
        resolved = NATIVE if size is None else f"{KEEP_ASPECT}{size}" if isinstance(size, int) else size
        return dataclasses.replace(self, size=resolved)

    @property
    def label(self) -> str:
        """The method and, when not the default, the views, for log lines: ``pixels``, ``netvlad, views raw,equalize``
        (D doubles with two views: said beside it)."""
        views = views_text(list(self.views))
        return self.method + (f", {views}" if views else "")

    @property
    def needs_fit(self) -> bool:
        """Whether images are needed to fit a PCA or the method's state."""
        return self.dim is not None or self.method_spec.fits_state

    def settings(self) -> dict[str, Any]:
        """JSON-ready settings that determine the descriptors (a resumed run must match them)."""
        spec = self.method_spec
        out: dict[str, Any] = {"method": self.method, "size": self.resolved().size, "crop_bottom": self.crop_bottom,
                               **dataclasses.asdict(spec), **spec.extra_settings()}
        if self.dim is not None:
            out.update(dim=self.dim, whiten=self.whiten)
        if self.views != DEFAULT_VIEWS:  # absent by default: the settings (and ids) of plain descriptors unchanged
            out.update(views=list(self.views))
        if self.needs_fit:
            out.update(fit=fit_summary(self.fit), fit_max=self.fit_max)
        return json.loads(json.dumps(out))


def check_size(size: Any) -> Size:
    """``"auto"``, ``"native"``, or ``(W, H)`` with ``1 <= W, H <= MAX_SIDE`` (from a pair or ``"WxH"``)."""
    if isinstance(size, str) and size.lower() in (AUTO, NATIVE):
        return size.lower()
    if isinstance(size, str) and size.lower().startswith(KEEP_ASPECT):
        width = size[len(KEEP_ASPECT):]
        if not width.isdigit() or not 1 <= int(width) <= MAX_SIDE:
            raise ConfigError(f"size keep-aspect:W needs a width W in 1..{MAX_SIDE}, got {size!r}")
        return f"{KEEP_ASPECT}{int(width)}"
    pair: Any = size
    if isinstance(size, str):
        pair = size.lower().split("x")
        pair = [int(v) for v in pair if v.strip().isdigit()] if len(pair) == 2 else []
    ok = isinstance(pair, Sequence) and len(pair) == 2
    ok = ok and all(isinstance(v, numbers.Integral) and not isinstance(v, bool) and 1 <= v <= MAX_SIDE for v in pair)
    if not ok:
        raise ConfigError(f"size must be 'auto', 'native', 'keep-aspect:W' or WIDTHxHEIGHT with both in "
                          f"1..{MAX_SIDE} (e.g. 640x320), got {size!r}")
    return int(pair[0]), int(pair[1])


def check_fit(fit: Any) -> Fit:
    """The fitting set: None, an int N >= 1, a folder / list file (str), or a tuple of image paths (or bag frames:
    :class:`~seqnet.describe.images.ImageItem`)."""
    if fit is None or isinstance(fit, str):
        return fit
    if isinstance(fit, os.PathLike):
        return os.fspath(fit)
    if isinstance(fit, int) and not isinstance(fit, bool):
        return check_int("fit (the first N images)", fit, 1)
    if isinstance(fit, Sequence) and fit and all(isinstance(p, (str, os.PathLike, ImageItem)) for p in fit):
        return tuple(p if isinstance(p, ImageItem) else os.fspath(p) for p in fit)
    raise ConfigError(f"fit must be an int N >= 1, a folder or list file, or a non-empty list of image paths, "
                      f"got {fit!r}")


def fit_summary(fit: Fit) -> Any:
    """``fit`` for the stored settings: a list of paths becomes its length and a hash."""
    if not isinstance(fit, tuple):
        return fit
    text = "\n".join(str(p if isinstance(p, ImageItem) else Path(p)) for p in fit)
    digest = hashlib.sha1(text.encode()).hexdigest()[:16]
    return {"paths": len(fit), "sha1": digest}
