"""NetVLAD (Arandjelović et al. 2016) with checkpoints in the pytorch-NetVlad / Patch-NetVLAD layout.

Checkpoint layout (a dict with ``state_dict``, as ``pitts_WPCA4096.pth.tar``)::

    encoder.{0,2,5,...,28}.weight/bias   VGG-16 conv1_1 .. conv5_3 (no final ReLU/pool)
    pool.conv.weight [K, C, 1, 1]        soft-assignment 1x1 conv (pool.conv.bias optional)
    pool.centroids   [K, C]              cluster centres
    WPCA.0.weight [P, K*C, 1, 1], WPCA.0.bias [P]   optional PCA-whitening 1x1 conv

Checkpoints written by seqnet may use the EfficientNet-Lite0 encoder; they say so under ``arch``. A checkpoint
is a stranger's file: ``arch`` and ``layer`` must be valid names and every layer's shape is checked in range
and against the tensors stored before the layer is built (:mod:`.weights`); anything else is one
:class:`CheckpointError` naming the file and the field.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ..core.errors import CheckpointError, ConfigError
from ..core.log import logger
from ..security.files import atomic_path
from ..security.torchfile import load_torch_file
from .cnn import BACKBONES, to_input
from .images import MAX_SIDE
from .weights import checked_state, pool_shape, wpca_shape

TAG_KEY = "seqnet_tag"  # provenance string stored in checkpoints written by seqnet (see save_netvlad)


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
    ckpt = load_torch_file(path, "NetVLAD checkpoint")
    if isinstance(ckpt, dict) and "state_dict" not in ckpt and any(str(k).startswith("pool.") for k in ckpt):
        ckpt = {"state_dict": ckpt}
    if not isinstance(ckpt, dict) or not isinstance(ckpt.get("state_dict"), dict):
        raise CheckpointError(f"{path}: expected a dict with 'state_dict' (pytorch-NetVlad / Patch-NetVLAD format)")
    checked_state(ckpt["state_dict"], path)
    return ckpt


def checkpoint_tag(path: str | os.PathLike[str]) -> str | None:
    """The provenance tag :func:`save_netvlad` stored in ``path``; None when absent or unreadable."""
    try:
        return _stored(path)[1]
    except CheckpointError:
        return None


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
    k, c = pool_shape(pool_state, path)
    arch, layer = encoder_choice(ckpt, path)
    wpca_state = _sub(state, "WPCA.0.") if use_wpca else {}
    p = wpca_shape(wpca_state, k * c, path) if wpca_state else None
    pool = NetVLAD(k, c, bias="conv.bias" in pool_state)  # every shape checked: the layers hold what is stored
    _load(pool, pool_state, f"{path}: pool")
    encoder = _load_encoder(arch, layer, _sub(state, "encoder."), path)
    if encoder.out_dim != c:
        raise CheckpointError(f"{path}: encoder gives {encoder.out_dim}-D features but pool.centroids are {c}-D")
    wpca = None
    if p is not None:
        wpca = nn.Conv2d(k * c, p, kernel_size=1, bias="bias" in wpca_state)
        _load(wpca, wpca_state, f"{path}: WPCA")
    logger.info("loaded NetVLAD %s: %s encoder, %d clusters x %d-D%s", path, arch, k, c,
                f", WPCA to {p}-D" if p is not None else "")
    return NetVLADModel(encoder, pool, wpca, arch=arch).eval()


def encoder_choice(ckpt: dict, path: str | os.PathLike[str]) -> tuple[str, str | int | None]:
    """``(arch, layer)`` a checkpoint names (defaults: vgg16, the backbone's local layer), both valid names."""
    arch = ckpt.get("arch", "vgg16")
    if not isinstance(arch, str) or arch not in BACKBONES:
        raise CheckpointError(f"{path}: unknown encoder arch {str(arch)[:60]!r}; valid: {', '.join(BACKBONES)}")
    backbone = BACKBONES[arch]
    try:
        return arch, backbone.check_layer(ckpt.get("layer", backbone.local_layer))
    except ConfigError as e:
        raise CheckpointError(f"{path}: the checkpoint's layer: {e}") from e


def _load(module: nn.Module, state: dict[str, torch.Tensor], where: str) -> None:
    try:
        module.load_state_dict(state, strict=True)
    except RuntimeError as e:
        raise CheckpointError(f"{where} weights do not fit ({str(e).splitlines()[0]})") from e


def _load_encoder(arch: str, layer: str | int | None, enc_state: dict[str, torch.Tensor],
                  path: str | os.PathLike[str]) -> nn.Module:
    if not enc_state:
        raise CheckpointError(f"{path}: checkpoint has no encoder.* weights (expected a VGG-16 conv encoder)")
    return BACKBONES[arch].from_state(enc_state, layer, str(path))


def checkpoint_image_size(path: str | os.PathLike[str]) -> tuple[int, int] | None:
    """The ``(W, H)`` a seqnet-written NetVLAD checkpoint was fitted at, or None (other checkpoints)."""
    return _stored(path)[0]


def _stored(path: str | os.PathLike[str]) -> tuple[tuple[int, int] | None, str | None]:
    """``(image size, provenance tag)`` seqnet stored in a checkpoint, read once per file state."""
    p = Path(path)
    stat = p.stat() if p.is_file() else None
    return _stored_metadata(str(p.resolve()), stat.st_mtime_ns if stat else 0, stat.st_size if stat else 0)


@functools.lru_cache(maxsize=16)
def _stored_metadata(path: str, mtime_ns: int, size_bytes: int) -> tuple[tuple[int, int] | None, str | None]:
    ckpt = read_checkpoint(path)  # keyed by the file's state: a rewritten file is read again
    size, tag = ckpt.get("image_size"), ckpt.get(TAG_KEY)
    ok = isinstance(size, list) and len(size) == 2 and all(
        isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= MAX_SIDE for v in size)
    return ((size[0], size[1]) if ok else None), (tag if isinstance(tag, str) else None)


def save_netvlad(model: NetVLADModel, path: str | os.PathLike[str], tag: str | None = None,
                 image_size: tuple[int, int] | int | None = None) -> Path:
    """Write ``model`` as a Patch-NetVLAD-style checkpoint (``{'state_dict': ..., 'arch': ...}``), atomically.

    ``tag``: a provenance string stored with it (read back by :func:`checkpoint_tag`); ``image_size``:
    the ``(W, H)`` its clusters were fitted at (read back by :func:`checkpoint_image_size`).
    """
    ckpt = {"state_dict": model.state_dict(), "arch": model.arch, "num_clusters": model.pool.num_clusters}
    if isinstance(image_size, tuple):
        ckpt["image_size"] = [int(v) for v in image_size]
    if hasattr(model.encoder, "layer"):
        ckpt["layer"] = model.encoder.layer
    if tag is not None:
        ckpt[TAG_KEY] = tag
    with atomic_path(path) as tmp:
        torch.save(ckpt, tmp)
    return Path(path)


def fit_netvlad(encoder: nn.Module, batches: Iterable[np.ndarray], n_images: int, clusters: int = 64,
                seed: int = 0, device: torch.device | str = "cpu", features_per_cluster: int = 50,
                what: str = "NetVLAD") -> NetVLADModel:
    """A NetVLAD model on ``encoder`` with clusters from k-means of local features of images.

    Args:
        encoder: backbone with ``arch``, ``out_dim``, ``mean``, ``std`` (see :mod:`seqnet.describe.cnn`).
        batches: uint8 image batches ``[B, H, W, 3]``.
        n_images: number of images in ``batches`` (to spread ~``features_per_cluster`` × K features).
        clusters: K.
        what: how the log line names the fit (``NetVLAD (equalize view)`` with several views).
    """
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
    logger.info("%s: %d clusters from %d local features of %d images", what, clusters, len(x), n_images)
    return NetVLADModel(encoder, pool, arch=encoder.arch).to(device).eval()
