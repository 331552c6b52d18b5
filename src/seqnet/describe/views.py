"""Photometric views of images: a describer with ``views`` describes each image once per view and concatenates the
views' descriptors (each L2-normalised, the whole divided by √views, so a row stays of unit norm).

:data:`VIEWS`: ``raw`` (the image as read) and ``equalize`` (each image's histogram equalised per channel, as
Pillow's ``ImageOps.equalize``: a snowfield or a dim frame spread over the whole range of grey levels). The
views of one place under two conditions differ in different ways, so their descriptors fail on different frames;
concatenated, the sequence models trained on them learn from both (docs/describe.md#views,
docs/benchmark_nordland64.md).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from ..core.errors import ConfigError

RAW = "raw"
DEFAULT_VIEWS = (RAW,)


def equalize(images: np.ndarray) -> np.ndarray:
    """Each image of ``images`` uint8 ``[B, H, W]`` or ``[B, H, W, C]`` with its histogram equalised per channel,
    exactly as Pillow's ``ImageOps.equalize`` (same dtype and shape): the lookup table of each image's channel is
    ``(step // 2 + count of darker pixels) // step`` with ``step = (pixels - pixels at the brightest level) // 255``;
    a channel of one level (or a step of 0) is left as it is. One image at a time: the working memory is one
    image's, not the batch's."""
    x = np.asarray(images)
    if x.dtype != np.uint8:
        raise ConfigError(f"equalize needs uint8 images, got {x.dtype}")
    out = np.empty_like(x)
    for k in range(len(x)):
        img = x[k] if x.ndim == 4 else x[k][..., None]  # [H, W, C]
        luts = np.stack([_lut(np.bincount(img[..., c].ravel(), minlength=256)) for c in range(img.shape[-1])])
        done = np.stack([luts[c][img[..., c]] for c in range(img.shape[-1])], axis=-1)  # uint8 indexing
        out[k] = done if x.ndim == 4 else done[..., 0]
    return out


def _lut(hist: np.ndarray) -> np.ndarray:
    """``[256]`` uint8: Pillow's equalisation table of one channel's histogram ``hist [256]``."""
    levels = np.flatnonzero(hist)
    step = (int(hist.sum()) - int(hist[levels[-1]])) // 255 if len(levels) else 0
    if len(levels) <= 1 or step == 0:
        return np.arange(256, dtype=np.uint8)
    darker = np.cumsum(hist) - hist
    return np.minimum((step // 2 + darker) // step, 255).astype(np.uint8)


VIEWS: dict[str, Callable[[np.ndarray], np.ndarray]] = {RAW: lambda images: images, "equalize": equalize}


def check_views(views: Sequence[str] | str) -> tuple[str, ...]:
    """``views`` as a tuple of distinct :data:`VIEWS` names (also ``"raw,equalize"``); else :class:`ConfigError`."""
    names = tuple(v.strip() for v in views.split(",")) if isinstance(views, str) else tuple(views)
    unknown = [v for v in names if v not in VIEWS]
    if not names or unknown or len(set(names)) != len(names):
        why = (f"unknown view {unknown[0]!r}" if unknown else "a view given twice" if names else "no view")
        raise ConfigError(f"views: {why} (give distinct names of {', '.join(VIEWS)}, e.g. raw,equalize)")
    return names


def described_views(images: np.ndarray, views: Sequence[str],
                    extract: Callable[[str, np.ndarray], np.ndarray]) -> np.ndarray:
    """``[B, views × D]`` float32: ``extract(view, images of that view)`` (``[B, ...] uint8 → [B, D]``: each view
    may have its own fitted state) of each view of ``images``, each row L2-normalised, concatenated in the order of
    ``views`` and divided by √views (rows of unit norm); one view: ``extract`` of the images as they are."""
    if len(views) == 1:
        return extract(views[0], VIEWS[views[0]](images))
    parts = []
    for v in views:
        d = np.asarray(extract(v, VIEWS[v](images)), dtype=np.float32)
        parts.append(d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12))
    return (np.concatenate(parts, axis=1) / np.float32(np.sqrt(len(parts)))).astype(np.float32)
