"""A plug-in describer for the tests (``--describer describe.plugin_describer:make``): the mean colour of
each cell of a 2 × 2 grid, L2-normalised (12-D), at its own input size."""

from __future__ import annotations

import torch
from torch import nn


class GridColour(nn.Module):
    image_size = (32, 16)  # (W, H): its --resize auto
    provenance = {"weights": "none", "version": 1}

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``[B, 3, H, W]`` in [0, 1] → ``[B, 12]``."""
        return nn.functional.normalize(nn.functional.adaptive_avg_pool2d(x, 2).flatten(1) + 1e-3, dim=1)


def make() -> nn.Module:
    return GridColour()


def not_a_module() -> object:
    return object()
