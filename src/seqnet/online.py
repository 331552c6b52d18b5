"""Incremental SeqMatch for a query stream (a robot localising frame by frame).

For each new query frame, :class:`OnlineSeqMatch` computes one distance row against the map (one
GEMV, ``N_db·D``) and sums the last ``L_m`` rows along the (anti-)diagonal (``L_m·N_db`` adds),
reusing the previous rows from a ring buffer instead of recomputing ``L_m`` GEMVs. The score row
of the window of the last ``L_m`` frames equals the batch definition
``Σ_t ‖q[i−L_m+1+t] − r[b+t]‖`` (:func:`seqnet.seqmatch.seqmatch`, a causal window).
"""

from __future__ import annotations

import numpy as np
import torch

from .blocks import topk_smallest
from .distances import finish_distances, sq_norms
from .errors import ConfigError
from .utils import ArrayLike, as_tensor, get_device
from .windows import check_seq_len


class OnlineSeqMatch:
    """Whole-map SeqMatch over a stream of query frames.

    Args:
        ref: ``[Nr, D]`` reference frame descriptors (the map; held in memory on ``device``).
        seq_len: L_m, the number of most recent query frames matched.
        reverse: match the reference traversed backwards (``r[b + L_m − 1 − t]``).
        device: torch device (default: CUDA when present).
    """

    def __init__(self, ref: ArrayLike, seq_len: int, reverse: bool = False, device: str | None = None) -> None:
        self.device = get_device(device)
        self.ref = as_tensor(ref, self.device, "reference", ndim=2, keep_float64=True)
        self.seq_len = check_seq_len(seq_len, len(self.ref), "seq_len")
        self.reverse = bool(reverse)
        self.r_sq = sq_norms(self.ref)
        self.rows = torch.zeros((self.seq_len, len(self.ref)), dtype=self.ref.dtype, device=self.device)
        self.count = 0  # frames seen since the last reset

    @property
    def n_windows(self) -> int:
        """Number of reference windows (``Nr − L_m + 1``): the length of a score row."""
        return len(self.ref) - self.seq_len + 1

    def reset(self) -> None:
        """Forget the frames seen (e.g. at a sequence bound)."""
        self.count = 0

    @torch.no_grad()
    def step(self, descriptor: ArrayLike) -> torch.Tensor | None:
        """Add a query frame ``[D]``; return the scores ``[Nr − L_m + 1]`` of its window (the last L_m
        frames) against every reference window start, or None until L_m frames have been seen."""
        q = as_tensor(descriptor, self.device, "query frame", keep_float64=True).to(self.ref.dtype).reshape(1, -1)
        if q.shape[1] != self.ref.shape[1]:
            raise ConfigError(f"dimension mismatch: query frame D={q.shape[1]}, map D={self.ref.shape[1]}")
        if not bool(torch.isfinite(q).all()):
            raise ConfigError(f"query frame {self.count} holds NaN or inf")
        row = finish_distances(q @ self.ref.T, sq_norms(q), self.r_sq)[0]
        self.rows[self.count % self.seq_len] = row
        self.count += 1
        if self.count < self.seq_len:
            return None
        nb, first = self.n_windows, self.count - self.seq_len
        out = torch.zeros(nb, dtype=self.ref.dtype, device=self.device)
        for t in range(self.seq_len):
            shift = self.seq_len - 1 - t if self.reverse else t
            out += self.rows[(first + t) % self.seq_len, shift : shift + nb]
        return out

    def topk(self, scores: torch.Tensor, k: int, starts: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` best ``(scores [k], items [k])`` of a score row (among the window ``starts`` when given)."""
        sub = scores if starts is None else scores[torch.as_tensor(starts, device=scores.device)]
        v, i = topk_smallest(sub[None, :], k)
        return v[0].cpu().numpy(), i[0].cpu().numpy()
