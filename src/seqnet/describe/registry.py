"""The :data:`DESCRIBERS` table: one small class per descriptor method.

A method class is a frozen dataclass whose fields are the :class:`~seqnet.describe.config.DescribeConfig`
keys that determine its raw descriptors (filled by :meth:`DescribeMethod.of`); its class attributes are its
defaults (input size, grey or RGB input, the suffix of the fitted state it keeps beside an output)
and :meth:`DescribeMethod.extractor` builds its function ``uint8 images [B, H, W(, 3)] → [B, D] float32``.
Adding a method = one class here + one entry in :data:`DESCRIBERS`.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from ..core.errors import ConfigError
from ..core.lazy import lazy_module
from ..core.log import logger
from .cnn import BACKBONES, cnn_extractor, gem, gmp, to_unit
from .pixels import pixels_descriptor

torch = lazy_module("torch")
nn = lazy_module("torch.nn")

Extract = Callable[[np.ndarray], np.ndarray]


CNN_SIZE = (640, 320)  # (W, H) the CNN methods resize to by default


@dataclasses.dataclass(frozen=True)
class FitContext:
    """What an extractor may need besides its settings.

    Attributes:
        device: torch device to run on.
        batches: ``batches()`` yields the fitting images as uint8 batches ``[B, H, W(, 3)]`` (as the method reads them).
        n_images: the number of fitting images.
        state: the file holding the method's fitted state (None: keep it in memory only).
        reuse: load ``state`` instead of fitting (it exists and was written for these settings).
        tag: provenance string to store in ``state`` when it is written.
        image_size: ``(W, H)`` (or a width) the fitting images are resized to; None: native.
        view: the view (:mod:`seqnet.describe.views`) the state is fitted on, when there are several; else None.
    """

    device: torch.device
    batches: Callable[[], Iterable[np.ndarray]]
    n_images: int
    state: Path | None = None
    reuse: bool = False
    tag: str | None = None
    image_size: tuple[int, int] | int | None = None
    view: str | None = None  # the view fitted, when the describer has several (named in the log line)


@dataclasses.dataclass(frozen=True)
class DescribeMethod:
    """Base class of the :data:`DESCRIBERS` entries (see the module docstring).

    A method whose extractor is fitted on images overrides :attr:`fits_state`, and sets
    :attr:`state_suffix` and :meth:`read_tag` so that its state can be kept beside an output.
    """

    name: ClassVar[str]
    summary: ClassVar[str]
    default_size: ClassVar[tuple[int, int] | None] = None  # (W, H) for size "auto"; None: native
    grey: ClassVar[bool] = False  # decode images as greyscale [B, H, W] instead of RGB [B, H, W, 3]
    state_suffix: ClassVar[str | None] = None  # fitted state kept beside an output as <stem><suffix>
    takes_describer: ClassVar[bool] = False  # its extractor is the user's --describer module

    def auto_size(self) -> tuple[int, int] | None:
        """The image size of ``size="auto"`` (default: :attr:`default_size`)."""
        return self.default_size

    @classmethod
    def of(cls, conf: Any) -> DescribeMethod:
        """The method's settings taken from a configuration object (its fields are attribute names)."""
        return cls(**{f.name: getattr(conf, f.name) for f in dataclasses.fields(cls)})

    @property
    def fits_state(self) -> bool:
        """Whether the extractor is fitted on images (and its state kept in :attr:`state_suffix` files)."""
        return False

    def read_tag(self, path: Path) -> str | None:
        """The provenance tag of a fitted-state file (None: not written by seqnet)."""
        return None

    def extra_settings(self) -> dict[str, Any]:
        """Settings beyond the fields that determine the descriptors (a plug-in's own provenance)."""
        return {}

    def bytes_per_pixel(self) -> int:
        """Peak working bytes per input pixel of each image in a batch (decoding and the extractor's
        activations; a CNN's from :data:`BACKBONES`, an unknown plug-in's assumed those of EfficientNet-Lite)."""
        backbone = getattr(self, "backbone", None)
        return BACKBONES[backbone].bytes_per_pixel if backbone else 300 if self.takes_describer else 64

    def extractor(self, ctx: FitContext) -> Extract:
        """The raw descriptor function ``uint8 [B, H, W(, 3)] → [B, D] float32``."""
        raise NotImplementedError


@dataclasses.dataclass(frozen=True)
class PixelsMethod(DescribeMethod):
    """SeqSLAM pixels: greyscale, patch-normalised (``patch``×``patch``), flattened, L2."""

    name = "pixels"
    summary = "greyscale pixels, patch-normalised, flattened (D = H*W)"
    grey = True
    patch: int

    def extractor(self, ctx: FitContext) -> Extract:
        return functools.partial(pixels_descriptor, size=None, patch=self.patch)


@dataclasses.dataclass(frozen=True)
class PooledMethod(DescribeMethod):
    """Base of the global poolings of a CNN map (a shipped backbone, or a NetVLAD checkpoint's encoder)."""

    default_size = CNN_SIZE
    backbone: str
    layer: str | int | None
    checkpoint: str | None

    def __post_init__(self) -> None:
        if not self.checkpoint and not BACKBONES[self.backbone].pretrained:
            raise ConfigError(f"the {self.backbone} backbone ships no weights; pass a NetVLAD checkpoint "
                              "(--checkpoint) whose encoder to use, or use --backbone efficientnet-lite0")

    def head(self) -> Callable[[torch.Tensor], torch.Tensor]:
        """Pooling ``[B, C, h, w]`` → ``[B, C]``, L2-normalised."""
        raise NotImplementedError

    def encoder(self) -> nn.Module:
        """The checkpoint's encoder, else the backbone cut at ``layer``."""
        from .netvlad import load_netvlad  # torch modules: loaded when NetVLAD runs

        if self.checkpoint:
            return load_netvlad(self.checkpoint, use_wpca=False).encoder
        return BACKBONES[self.backbone].build(self.layer)

    def extractor(self, ctx: FitContext) -> Extract:
        return cnn_extractor(self.encoder(), self.head(), ctx.device)


@dataclasses.dataclass(frozen=True)
class GeMMethod(PooledMethod):
    name = "gem"
    summary = "generalised-mean pooling (power --gem-p) of a CNN map"
    gem_p: float

    def head(self) -> Callable[[torch.Tensor], torch.Tensor]:
        return functools.partial(gem, p=self.gem_p)


@dataclasses.dataclass(frozen=True)
class GMPMethod(PooledMethod):
    name = "gmp"
    summary = "global max pooling of a CNN map"

    def head(self) -> Callable[[torch.Tensor], torch.Tensor]:
        return gmp


@dataclasses.dataclass(frozen=True)
class NetVLADMethod(DescribeMethod):
    """NetVLAD from a checkpoint, or with clusters fitted by k-means over a shipped backbone."""

    name = "netvlad"
    summary = "NetVLAD (a pytorch-NetVlad / Patch-NetVLAD checkpoint, or clusters fitted on images)"
    default_size = CNN_SIZE
    state_suffix = ".netvlad.pth.tar"
    backbone: str
    layer: str | int | None
    checkpoint: str | None
    use_wpca: bool
    clusters: int
    seed: int

    def __post_init__(self) -> None:
        if not self.checkpoint and not BACKBONES[self.backbone].pretrained:
            raise ConfigError(f"NetVLAD without a checkpoint needs a pretrained backbone; {self.backbone!r} has no "
                              "shipped weights (hint: --backbone efficientnet-lite0, or pass --checkpoint)")

    @property
    def fits_state(self) -> bool:
        return not self.checkpoint

    def auto_size(self) -> tuple[int, int] | None:
        """The size a seqnet-written checkpoint was fitted at (describing at another silently ruins it)."""
        from .netvlad import checkpoint_image_size  # torch modules: loaded when NetVLAD runs

        stored = checkpoint_image_size(self.checkpoint) if self.checkpoint else None
        return stored or self.default_size

    def read_tag(self, path: Path) -> str | None:
        from .netvlad import checkpoint_tag  # torch modules: loaded when NetVLAD runs

        return checkpoint_tag(path)

    def extractor(self, ctx: FitContext) -> Extract:
        from .netvlad import fit_netvlad, load_netvlad, save_netvlad  # torch modules: loaded when NetVLAD runs

        if self.checkpoint:
            model = load_netvlad(self.checkpoint, use_wpca=self.use_wpca)
        elif ctx.reuse and ctx.state is not None:
            logger.info("reusing the NetVLAD clusters of %s", ctx.state)
            model = load_netvlad(ctx.state)
        else:
            if ctx.n_images < 1:
                raise ConfigError("NetVLAD without a checkpoint needs images to fit its clusters on (hint: --fit-on)")
            backbone = BACKBONES[self.backbone]
            encoder = backbone.build(backbone.local_layer if self.layer is None else self.layer)
            model = fit_netvlad(encoder, ctx.batches(), ctx.n_images, self.clusters, self.seed, ctx.device,
                                what="NetVLAD" + (f" ({ctx.view} view)" if ctx.view else ""))
            if ctx.state is not None:
                save_netvlad(model, ctx.state, tag=ctx.tag, image_size=ctx.image_size)
        return cnn_extractor(model, lambda v: v, ctx.device)


@functools.lru_cache(maxsize=8)
def load_plugin(spec: str) -> nn.Module:
    """The module ``factory()`` of ``spec`` = ``"package.module:factory"`` returns (see :class:`PluginMethod`)."""
    import importlib

    module_name, _, attr = spec.partition(":")
    if not module_name or not attr:
        raise ConfigError(f"--describer {spec!r}: expected 'package.module:factory'")
    try:
        factory = getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as e:
        raise ConfigError(f"--describer {spec!r}: cannot import it ({e}); hint: the package must be importable "
                          "(installed, or on PYTHONPATH)") from e
    net = factory()
    if not isinstance(net, nn.Module):
        raise ConfigError(f"--describer {spec!r}: factory() returned {type(net).__name__}, not a torch.nn.Module")
    return net


@dataclasses.dataclass(frozen=True)
class PluginMethod(DescribeMethod):
    """Your own describer: ``--describer package.module:factory``. ``factory()`` returns a ``torch.nn.Module``
    mapping RGB images ``[B, 3, H, W]`` float in [0, 1] to descriptors ``[B, D]``; its own normalisation is
    its business. An attribute ``image_size = (W, H)`` on the module is its ``--resize auto`` size (default
    native), and ``provenance`` (a JSON-able value, e.g. a checkpoint hash) is recorded beside the spec."""

    name = "plugin"
    summary = "your own torch module (--describer package.module:factory)"
    takes_describer = True
    describer: str | None

    def __post_init__(self) -> None:
        if not self.describer:
            raise ConfigError("--method plugin needs --describer package.module:factory")

    @property
    def net(self) -> nn.Module:
        return load_plugin(str(self.describer))  # built once per spec

    def extra_settings(self) -> dict[str, Any]:
        return {"describer_provenance": getattr(self.net, "provenance", None)}

    def auto_size(self) -> tuple[int, int] | None:
        size = getattr(self.net, "image_size", None)
        return tuple(size) if size is not None else None  # type: ignore[return-value]

    def extractor(self, ctx: FitContext) -> Extract:
        net = self.net.to(ctx.device).eval()

        @torch.inference_mode()
        def extract(images: np.ndarray) -> np.ndarray:
            return net(to_unit(images, ctx.device)).float().cpu().numpy()

        return extract


DESCRIBERS: dict[str, type[DescribeMethod]] = {m.name: m for m in (PixelsMethod, GeMMethod, GMPMethod, NetVLADMethod,
                                                             PluginMethod)}
