"""Binary codes of frame descriptors for GRH's relocalisation candidates: learned (deep hashing) and their search.

**Hamming search** (:func:`hamming_topk`): the ``c`` reference codes nearest to each query code,
ties broken by the lower frame. Distances are exact integers: for bits ``b ∈ {0, 1}``,
``ham(x, y) = |x| + |y| − 2 x·y`` (one GEMM per block of queries; exact in float32 below 2^24 bits),
the same count as a popcount of ``x XOR y``. Both ``grh`` (LSH codes) and ``grh-dh`` use it.

**Learned codes** (:func:`train_hash`, ``grh-dh``): a :class:`HashNet` (standardise, one linear layer
D → nbits; ``tanh`` while training, the sign at use; the bits are ``W x + b ≥ 0``) trained as a deep
supervised hashing network (DSH, Liu et al. 2016): a contrastive loss on the relaxed normalised
Hamming distance ``d = (nbits − h_a·h_b) / (2 nbits) ∈ [0, 1]`` of pairs (positives ``d²``, negatives
``max(0, margin − d)²``) plus a quantisation term ``quant · mean(| |h| − 1 |)`` that pulls the relaxed
codes to ±1. Pairs are drawn from the frames it is trained on, in their recorded order: a positive is
a frame within ``pos_frames`` of the anchor, a negative one more than ``neg_frames`` away
(:func:`sample_pairs`). Initialised with a seeded Gaussian W (= random-hyperplane LSH before training)
and trained with Adam on CPU from a seeded generator: deterministic.

:func:`dh_candidates` trains the network on the **reference** frames given (the map being searched,
no query frame and no ground truth: what differs from the paper's GRH:DH is in ``docs/matchers.md``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..core.config import Config, check_float, check_int
from ..core.devices import get_device
from ..core.errors import ConfigError
from ..core.lazy import lazy_module, no_grad
from ..core.tensors import ArrayLike, to_numpy
from ..search.blocks import topk_smallest
from ..search.knn import as_pair, rows_per_block, sq_norms

torch = lazy_module("torch")


@dataclasses.dataclass(frozen=True)
class HashSettings(Config):
    """How :func:`train_hash` trains (see the module docstring); the defaults are ``grh-dh``'s."""

    steps: int = 100
    batch: int = 128
    lr: float = 0.01
    margin: float = 0.5
    quant: float = 0.1
    pos_frames: int = 2
    neg_frames: int = 20
    seed: int = 0

    def __post_init__(self) -> None:
        for key in ("steps", "batch", "pos_frames", "neg_frames", "seed"):
            self._set(key, check_int(key, getattr(self, key), 1 if key in ("steps", "batch", "pos_frames") else 0))
        for key in ("lr", "margin", "quant"):
            self._set(key, check_float(key, getattr(self, key), 0.0))


class HashNet:
    """``x [N, D]`` → relaxed codes ``tanh(W (x − μ) / s + b) [N, nbits]``; :meth:`bits` the signs as {0, 1}.

    ``W, b``: one ``torch.nn.Linear(D, nbits)``; ``μ`` is the training frames' mean and ``s`` their mean
    centred norm (so ``‖(x − μ) / s‖ ≈ 1``). (A plain class holding the layer: torch loads lazily.)
    """

    def __init__(self, frames: torch.Tensor, nbits: int, generator: torch.Generator):
        self.mean = frames.mean(0)
        self.scale = (frames - self.mean).norm(dim=1).mean().clamp_min(1e-12)
        self.linear = torch.nn.Linear(frames.shape[1], nbits)
        with torch.no_grad():
            self.linear.weight.copy_(torch.randn(nbits, frames.shape[1], generator=generator))
            self.linear.bias.zero_()

    def logits(self, x: torch.Tensor) -> torch.Tensor:
        """``[N, nbits]``: ``W (x − μ) / s + b``."""
        return self.linear((x - self.mean) / self.scale)

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        """The relaxed codes ``[N, nbits]`` in (−1, 1)."""
        return torch.tanh(self.logits(x))

    @no_grad
    def bits(self, x: torch.Tensor) -> torch.Tensor:
        """``[N, nbits]`` float {0, 1}: ``logits ≥ 0`` (the sign of the code)."""
        return (self.logits(x.to(self.mean)) >= 0).float()


def sample_pairs(n: int, batch: int, pos_frames: int, neg_frames: int,
                 generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(anchor, positive, negative)`` frame indices ``[batch]`` of ``n`` ordered frames.

    A positive is within ``pos_frames`` of the anchor (another frame when n > 1), a negative more
    than ``neg_frames`` away (``neg_frames`` capped at ``(n − 2) // 2`` so that one exists).
    """
    neg = max(0, min(neg_frames, (n - 2) // 2))
    a = torch.randint(n, (batch,), generator=generator)
    off = torch.randint(1, max(1, pos_frames) + 1, (batch,), generator=generator)
    sign = torch.where(torch.rand(batch, generator=generator) < 0.5, -1, 1)
    p = a + sign * off
    p = torch.where((p < 0) | (p >= n), a - sign * off, p).clamp(0, n - 1)
    span = max(1, n - 2 * neg - 1)
    c = (a + neg + 1 + torch.randint(span, (batch,), generator=generator)) % n  # circular distance > neg
    return a, p, c


def hash_loss(h_a: torch.Tensor, h_p: torch.Tensor, h_n: torch.Tensor, margin: float, quant: float) -> torch.Tensor:
    """The DSH loss of relaxed codes ``[B, nbits]`` of anchors, positives and negatives (module docstring)."""
    nbits = h_a.shape[1]

    def dist(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return (nbits - (x * y).sum(1)) / (2 * nbits)

    codes = torch.cat([h_a, h_p, h_n])
    return (dist(h_a, h_p).square().mean() + (margin - dist(h_a, h_n)).clamp_min(0).square().mean()
            + quant * (codes.abs() - 1).abs().mean())


@dataclasses.dataclass
class HashTraining:
    """What :func:`train_hash` returns: the trained network and the loss of each step."""

    net: HashNet
    losses: np.ndarray  # [steps]


def train_hash(frames: ArrayLike, nbits: int = 256, settings: HashSettings | None = None) -> HashTraining:
    """Train a :class:`HashNet` on the ordered frame descriptors ``frames [N, D]`` (CPU, float32, seeded)."""
    s = settings or HashSettings()
    nbits = check_int("nbits", nbits, 1)
    x = torch.as_tensor(to_numpy(frames), dtype=torch.float32)
    gen = torch.Generator().manual_seed(s.seed)
    net = HashNet(x, nbits, gen)
    opt = torch.optim.Adam(net.linear.parameters(), lr=s.lr)
    losses = np.zeros(s.steps)
    with torch.enable_grad():
        for step in range(s.steps):
            a, p, c = sample_pairs(len(x), s.batch, s.pos_frames, s.neg_frames, gen)
            loss = hash_loss(net(x[a]), net(x[p]), net(x[c]), s.margin, s.quant)
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses[step] = float(loss.detach())
    return HashTraining(net, losses)


@no_grad
def hamming_topk(q_bits: torch.Tensor, r_bits: torch.Tensor, candidates: int,
                 block_bytes: int | None = None) -> np.ndarray:
    """``[Nq, min(candidates, Nr)]``: the reference codes ``r_bits [Nr, B]`` nearest to each query code
    ``q_bits [Nq, B]`` (float {0, 1}, one device) in Hamming distance, nearest first, ties by the lower frame."""
    candidates = check_int("candidates", candidates, 1)
    if q_bits.shape[1] >= 2**24:
        raise ConfigError(f"nbits={q_bits.shape[1]}: Hamming distances in float32 are exact below 2^24 bits; "
                          "hint: fewer bits")
    out = np.zeros((len(q_bits), min(candidates, len(r_bits))), dtype=np.int64)
    rows = rows_per_block(4 * len(r_bits) * 2, block_bytes)
    r_sq = sq_norms(r_bits)
    for s in range(0, len(q_bits), rows):
        qb = q_bits[s : s + rows]
        ham = sq_norms(qb)[:, None] + r_sq[None, :] - 2 * qb @ r_bits.T
        out[s : s + rows] = to_numpy(topk_smallest(ham, candidates)[1])
    return out


@no_grad
def dh_candidates(query: ArrayLike, ref: ArrayLike, nbits: int = 256, candidates: int = 20,
                  device: str | None = None, block_bytes: int | None = None,
                  settings: HashSettings | None = None) -> np.ndarray:
    """``[Nq, min(candidates, Nr)]`` reference frames nearest to each query frame in the Hamming distance of
    learned codes: a :class:`HashNet` trained on ``ref`` (:func:`train_hash`), then :func:`hamming_topk`."""
    nbits, candidates = check_int("nbits", nbits, 1), check_int("candidates", candidates, 1)
    q, r = (t.float() for t in as_pair(query, ref, torch.device("cpu")))
    net = train_hash(r, nbits, settings).net
    dev = get_device(device)
    return hamming_topk(net.bits(q).to(dev), net.bits(r).to(dev), candidates, block_bytes)
