"""NetVLAD (Arandjelović et al. 2016) with checkpoints in the pytorch-NetVlad / Patch-NetVLAD layout.

Checkpoint layout (a dict with ``state_dict``, as ``pitts_WPCA4096.pth.tar``)::

    encoder.{0,2,5,...,28}.weight/bias   VGG-16 conv1_1 .. conv5_3 (no final ReLU/pool)
    pool.conv.weight [K, C, 1, 1]        soft-assignment 1x1 conv (pool.conv.bias optional)
    pool.centroids   [K, C]              cluster centres
    WPCA.0.weight [P, K*C, 1, 1], WPCA.0.bias [P]   optional PCA-whitening 1x1 conv

Checkpoints written by seqnet may use the EfficientNet-Lite0 encoder; they say so under ``arch``.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ..errors import CheckpointError, ConfigError
from ..files import atomic_path
from ..utils import logger
from .cnn import EfficientNetLite0, VGG16Encoder

NETVLAD_LAYER = 10  # EfficientNet-Lite0 block 10: 112 channels at stride 16 (like VGG-16 conv5_3)


class NetVLAD(nn.Module):
    """NetVLAD pooling ``[B, C, H, W]`` → ``[B, K*C]`` (input L2 per location, intra-norm, L2)."""

    def __init__(self, num_clusters: int = 64, dim: int = 512, bias: bool = False) -> None:
        super().__init__()
        self.num_clusters, self.dim = int(num_clusters), int(dim)
        self.conv = nn.Conv2d(dim, num_clusters, kernel_size=1, bias=bias)
        self.centroids = nn.Parameter(torch.rand(num_clusters, dim))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = F.normalize(x, p=2, dim=1)
        assign = F.softmax(self.conv(x).flatten(2), dim=1)  # [B, K, P]
        xf = x.flatten(2)  # [B, C, P]
        vlad = torch.einsum("bkp,bcp->bkc", assign, xf) - assign.sum(-1).unsqueeze(-1) * self.centroids
        vlad = F.normalize(vlad, p=2, dim=2)
        return F.normalize(vlad.flatten(1), p=2, dim=1)

    @torch.no_grad()
    def init_from_clusters(self, centroids: np.ndarray, features: np.ndarray) -> None:
        """Set centres and the assignment conv as pytorch-NetVlad does (``alpha`` from the data).

        ``centroids`` ``[K, C]`` (k-means of L2-normalised local features), ``features`` ``[M, C]``.
        """
        c = centroids / np.maximum(np.linalg.norm(centroids, axis=1, keepdims=True), 1e-12)
        dots = np.sort(c @ features.T, axis=0)[::-1]
        alpha = float(-np.log(0.01) / max(np.mean(dots[0] - dots[1]), 1e-6))
        self.centroids.copy_(torch.from_numpy(centroids.astype(np.float32)))
        self.conv.weight.copy_(torch.from_numpy((alpha * c).astype(np.float32))[:, :, None, None])
        if self.conv.bias is not None:
            self.conv.bias.zero_()


class NetVLADModel(nn.Module):
    """Encoder + NetVLAD (+ optional WPCA): uint8-normalised images ``[B, 3, H, W]`` → ``[B, D]``."""

    def __init__(self, encoder: nn.Module, pool: NetVLAD, wpca: nn.Conv2d | None = None, arch: str = "vgg16") -> None:
        super().__init__()
        self.encoder, self.pool, self.arch = encoder, pool, arch
        self.WPCA = nn.Sequential(wpca) if wpca is not None else None
        self.mean, self.std = encoder.mean, encoder.std

    @property
    def out_dim(self) -> int:
        return int(self.WPCA[0].out_channels) if self.WPCA is not None else self.pool.num_clusters * self.pool.dim

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        v = self.pool(self.encoder(x))
        if self.WPCA is not None:
            v = F.normalize(self.WPCA(v[:, :, None, None]).flatten(1), p=2, dim=1)
        return v


def local_features(encoder: nn.Module, x: torch.Tensor, per_image: int, generator: torch.Generator) -> torch.Tensor:
    """Up to ``per_image`` random L2-normalised local features ``[B*n, C]`` of the encoder map of ``x``."""
    f = F.normalize(encoder(x), p=2, dim=1).flatten(2)  # [B, C, P]
    n = min(per_image, f.shape[2])
    idx = torch.stack([torch.randperm(f.shape[2], generator=generator)[:n] for _ in range(f.shape[0])])
    picked = torch.gather(f, 2, idx[:, None, :].expand(-1, f.shape[1], -1).to(f.device))  # [B, C, n]
    return picked.permute(0, 2, 1).reshape(-1, f.shape[1])


def kmeans(x: np.ndarray, k: int, seed: int = 0, iters: int = 50) -> np.ndarray:
    """k-means centres ``[k, C]`` of ``x`` ``[M, C]`` (faiss); raises :class:`ConfigError` if M < k."""
    if x.shape[0] < k:
        raise ConfigError(
            f"k-means for {k} NetVLAD clusters needs at least {k} local features, got {x.shape[0]} "
            "(hint: fit on more or larger images, or use fewer clusters)"
        )
    import faiss

    km = faiss.Kmeans(x.shape[1], k, niter=iters, seed=seed, verbose=False, max_points_per_centroid=10_000)
    km.train(np.ascontiguousarray(x, dtype=np.float32))
    return np.asarray(km.centroids, dtype=np.float32)


# ----------------------------------------------------------------------------- checkpoints


def _strip(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Remove DataParallel ``module.`` parts of keys."""
    return {k.replace("module.", ""): v for k, v in state.items()}


def _sub(state: dict[str, torch.Tensor], prefix: str) -> dict[str, torch.Tensor]:
    return {k[len(prefix):]: v for k, v in state.items() if k.startswith(prefix)}


def read_checkpoint(path: str | os.PathLike[str]) -> dict:
    """The raw checkpoint dict (``state_dict`` + metadata); :class:`CheckpointError` when unreadable."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"NetVLAD checkpoint not found: {path}")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - torch raises many types for a bad file
        reason = f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"
        raise CheckpointError(f"cannot read NetVLAD checkpoint {path} ({reason})") from None
    if isinstance(ckpt, dict) and "state_dict" not in ckpt and any(k.startswith("pool.") for k in ckpt):
        ckpt = {"state_dict": ckpt}
    if not isinstance(ckpt, dict) or not isinstance(ckpt.get("state_dict"), dict):
        raise CheckpointError(f"{path}: expected a dict with 'state_dict' (pytorch-NetVlad / Patch-NetVLAD format)")
    return ckpt


def load_netvlad(path: str | os.PathLike[str], use_wpca: bool = True) -> NetVLADModel:
    """Load a NetVLAD model (encoder, ``pool.*``, optional ``WPCA.0.*``) from a checkpoint file."""
    ckpt = read_checkpoint(path)
    state = _strip(ckpt["state_dict"])
    pool_state = _sub(state, "pool.")
    need = ("conv.weight", "centroids")
    if any(k not in pool_state for k in need):
        found = sorted({k.split(".")[0] for k in state})
        raise CheckpointError(
            f"{path}: not a NetVLAD checkpoint: needs pool.conv.weight and pool.centroids "
            f"(found top-level keys: {', '.join(found) or 'none'}; expected encoder.*, pool.*, optional WPCA.0.*)"
        )
    k, c = pool_state["centroids"].shape
    pool = NetVLAD(k, c, bias="conv.bias" in pool_state)
    _load(pool, pool_state, f"{path}: pool")
    encoder = _load_encoder(ckpt, _sub(state, "encoder."), path)
    if encoder.out_dim != c:
        raise CheckpointError(f"{path}: encoder gives {encoder.out_dim}-D features but pool.centroids are {c}-D")
    wpca = None
    if use_wpca and "WPCA.0.weight" in state:
        w = state["WPCA.0.weight"]
        if w.ndim != 4 or w.shape[1] != k * c:
            raise CheckpointError(f"{path}: WPCA.0.weight has shape {tuple(w.shape)}, expected [P, {k * c}, 1, 1]")
        wpca = nn.Conv2d(k * c, w.shape[0], kernel_size=1, bias="WPCA.0.bias" in state)
        _load(wpca, _sub(state, "WPCA.0."), f"{path}: WPCA")
    logger.info("loaded NetVLAD %s: %s encoder, %d clusters x %d-D%s", path, ckpt.get("arch", "vgg16"), k, c,
                f", WPCA to {wpca.out_channels}-D" if wpca is not None else "")
    return NetVLADModel(encoder, pool, wpca, arch=ckpt.get("arch", "vgg16")).eval()


def _load(module: nn.Module, state: dict[str, torch.Tensor], where: str) -> None:
    try:
        module.load_state_dict(state, strict=True)
    except RuntimeError as e:
        raise CheckpointError(f"{where} weights do not fit ({str(e).splitlines()[0]})") from None


def _load_encoder(ckpt: dict, enc_state: dict[str, torch.Tensor], path: Path) -> nn.Module:
    arch = ckpt.get("arch", "vgg16")
    if not enc_state:
        raise CheckpointError(f"{path}: checkpoint has no encoder.* weights (expected a VGG-16 conv encoder)")
    if arch == "vgg16":
        return VGG16Encoder.from_state_dict(enc_state, str(path))
    if arch == "efficientnet-lite0":
        enc = EfficientNetLite0(layer=ckpt.get("layer", NETVLAD_LAYER), pretrained=False)
        _load(enc, enc_state, f"{path}: encoder")
        return enc
    raise CheckpointError(f"{path}: unknown encoder arch {arch!r}; valid: vgg16, efficientnet-lite0")


def save_netvlad(model: NetVLADModel, path: str | os.PathLike[str]) -> Path:
    """Write ``model`` as a Patch-NetVLAD-style checkpoint (``{'state_dict': ..., 'arch': ...}``), atomically."""
    ckpt = {"state_dict": model.state_dict(), "arch": model.arch, "num_clusters": model.pool.num_clusters}
    if isinstance(model.encoder, EfficientNetLite0):
        ckpt["layer"] = model.encoder.layer
    with atomic_path(path) as tmp:
        torch.save(ckpt, tmp)
    return Path(path)


def fit_netvlad(encoder: nn.Module, batches: Iterable[np.ndarray], n_images: int, clusters: int = 64,
                seed: int = 0, device: torch.device | str = "cpu", features_per_cluster: int = 50) -> NetVLADModel:
    """A NetVLAD model on ``encoder`` with clusters from k-means of local features of images.

    Args:
        encoder: backbone with ``out_dim``, ``mean``, ``std`` (see :mod:`seqnet.backbones`).
        batches: uint8 image batches ``[B, H, W, 3]``.
        n_images: number of images in ``batches`` (to spread ~``features_per_cluster`` × K features).
        clusters: K.
    """
    from .cnn import to_input

    encoder = encoder.to(device).eval()
    gen = torch.Generator().manual_seed(seed)
    per_image = max(1, -(-features_per_cluster * clusters // max(n_images, 1)))
    feats = []
    with torch.inference_mode():
        for imgs in batches:
            x = to_input(imgs, encoder.mean, encoder.std, torch.device(device))
            feats.append(local_features(encoder, x, per_image, gen).cpu())
    x = torch.cat(feats).numpy() if feats else np.zeros((0, encoder.out_dim), np.float32)
    pool = NetVLAD(clusters, encoder.out_dim)
    pool.init_from_clusters(kmeans(x, clusters, seed=seed), x)
    logger.info("NetVLAD: %d clusters from %d local features of %d images", clusters, len(x), n_images)
    arch = "efficientnet-lite0" if isinstance(encoder, EfficientNetLite0) else "vgg16"
    return NetVLADModel(encoder, pool, arch=arch).to(device).eval()


def netvlad_for(checkpoint: str | None = None, use_wpca: bool = True, cache: Path | None = None,
                backbone: str = "efficientnet-lite0", layer: str | int | None = None, clusters: int = 64,
                seed: int = 0, device: torch.device | str = "cpu",
                fit_batches: Callable[[], Iterable[np.ndarray]] | None = None, n_fit: int = 0) -> NetVLADModel:
    """A NetVLAD model: from ``checkpoint``; else from ``cache`` when it exists; else clusters fitted by
    k-means on ``fit_batches()`` (uint8 image batches) over a shipped backbone, saved to ``cache``."""
    from .cnn import build_backbone

    if checkpoint:
        return load_netvlad(checkpoint, use_wpca=use_wpca)
    if cache is not None and cache.is_file():
        logger.info("resuming with the NetVLAD clusters of %s", cache)
        return load_netvlad(cache)
    if backbone != "efficientnet-lite0":
        raise ConfigError(f"NetVLAD without a checkpoint needs a pretrained backbone; {backbone!r} has no shipped "
                          "weights (hint: --backbone efficientnet-lite0, or pass --checkpoint)")
    if fit_batches is None or n_fit < 1:
        raise ConfigError("NetVLAD without a checkpoint needs images to fit its clusters on (hint: --fit-on)")
    encoder = build_backbone(backbone, NETVLAD_LAYER if layer is None else layer)
    model = fit_netvlad(encoder, fit_batches(), n_fit, clusters, seed, device)
    if cache is not None:
        save_netvlad(model, cache)
    return model
