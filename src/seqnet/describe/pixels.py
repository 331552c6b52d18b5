"""SeqSLAM-style "pixels" descriptor: greyscale, downsample, patch-normalise, flatten, L2.

All functions are pure and vectorised over a batch of images ``[N, H, W]`` or ``[N, H, W, C]``.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError
from ..core.lazy import lazy_module

torch = lazy_module("torch")
F = lazy_module("torch.nn.functional")

GREY_WEIGHTS = np.array([0.299, 0.587, 0.114], dtype=np.float32)  # ITU-R BT.601 luma


def to_grey(images: np.ndarray) -> np.ndarray:
    """Greyscale float32 images ``[N, H, W]`` in [0, 1] from ``[N, H, W]`` or ``[N, H, W, 1|3|4]``.

    uint8 input is scaled by 1/255; float input is kept as is (any range works for patch
    normalisation, which is scale-invariant).
    """
    x = np.asarray(images)
    if x.ndim not in (3, 4):
        raise ConfigError(f"images must be [N, H, W] or [N, H, W, C], got shape {x.shape}")
    scale = 1.0 / 255.0 if x.dtype == np.uint8 else 1.0
    x = x.astype(np.float32) * np.float32(scale)
    if x.ndim == 3:
        return x
    c = x.shape[-1]
    if c == 1:
        return x[..., 0]
    if c in (3, 4):
        return x[..., :3] @ GREY_WEIGHTS
    raise ConfigError(f"images must have 1, 3 or 4 channels, got {c} (shape {x.shape})")


def resize(grey: np.ndarray, size: tuple[int, int] | None) -> np.ndarray:
    """Resize greyscale images ``[N, H, W]`` to ``size=(W, H)`` (antialiased bilinear); None keeps them."""
    if size is None:
        return grey
    w, h = (int(v) for v in size)
    if w < 1 or h < 1:
        raise ConfigError(f"resize size must be (width, height) with both >= 1, got {size}")
    if grey.shape[1:] == (h, w):
        return grey
    t = torch.from_numpy(np.ascontiguousarray(grey))[:, None]
    out = F.interpolate(t, size=(h, w), mode="bilinear", antialias=True, align_corners=False)
    return out[:, 0].numpy()


def patch_normalise(grey: np.ndarray, patch: int = 8, eps: float = 1e-6) -> np.ndarray:
    """Normalise each ``patch``×``patch`` block of ``[N, H, W]`` images to zero mean, unit variance.

    Edge blocks are smaller when H or W is not a multiple of ``patch``. A flat block (standard
    deviation below ``eps``) becomes all zeros. ``patch=0`` or 1 disables the normalisation.
    """
    if patch < 0:
        raise ConfigError(f"patch size must be >= 0, got {patch}")
    if patch <= 1:
        return grey.astype(np.float32, copy=False)
    n, h, w = grey.shape
    ph, pw = -h % patch, -w % patch
    x = np.pad(grey.astype(np.float64), ((0, 0), (0, ph), (0, pw)), constant_values=np.nan)
    hb, wb = x.shape[1] // patch, x.shape[2] // patch
    blocks = x.reshape(n, hb, patch, wb, patch)
    mean = np.nanmean(blocks, axis=(2, 4), keepdims=True)
    std = np.sqrt(np.nanmean((blocks - mean) ** 2, axis=(2, 4), keepdims=True))
    out = (blocks - mean) / np.maximum(std, eps)
    out = np.where(std < eps, 0.0, out)
    return out.reshape(n, hb * patch, wb * patch)[:, :h, :w].astype(np.float32)


def l2_rows(x: np.ndarray, eps: float = 1e-12) -> np.ndarray:
    """L2-normalise the rows of ``[N, D]`` (zero rows stay zero)."""
    norms = np.linalg.norm(x, axis=1, keepdims=True)
    return (x / np.maximum(norms, eps)).astype(np.float32)


def pixels_descriptor(
    images: np.ndarray, size: tuple[int, int] | None = None, patch: int = 8, eps: float = 1e-6
) -> np.ndarray:
    """SeqSLAM "pixels" descriptors ``[N, D]`` float32 (D = H'·W') of a batch of images.

    Args:
        images: ``[N, H, W]`` or ``[N, H, W, 3]`` uint8 (0..255) or float images.
        size: ``(W, H)`` to resize to; None keeps the native size (e.g. 64×32 Nordland frames).
        patch: patch-normalisation block size (default 8; 0 disables).
        eps: standard deviation below which a patch counts as flat (set to zero).

    Returns:
        ``[N, H'·W']`` float32, each row L2-normalised.
    """
    grey = resize(to_grey(images), size)
    normed = patch_normalise(grey, patch=patch, eps=eps)
    return l2_rows(normed.reshape(normed.shape[0], -1))
