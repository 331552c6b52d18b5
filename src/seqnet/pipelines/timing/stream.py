"""The paper's "SeqMatch: All" per-query cost, ours: whole-map SeqMatch for a stream with nothing but the matcher
(:class:`OnlineSeqMatch`), so the compute-time table times the matcher alone. The localiser does the same work
inside :class:`seqnet.localize.localizer.Localizer` (the matchers' online forms); this class lives here because
only the timing uses it."""

from __future__ import annotations

import numpy as np

from ...core.devices import get_device
from ...core.errors import ConfigError
from ...core.lazy import lazy_module, no_grad
from ...core.tensors import ArrayLike, as_tensor
from ...matching.online import Ring, seqmatch_window
from ...search.blocks import topk_smallest
from ...search.knn import ExactIndex
from ...sequence.windows import check_seq_len

torch = lazy_module("torch")


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
        self.index = ExactIndex(self.ref, self.device)  # its norms are computed once; one GEMV per frame
        self.rows = Ring(self.seq_len, len(self.ref), self.ref.dtype, self.device)

    @property
    def count(self) -> int:
        """Frames seen since the last reset."""
        return self.rows.count

    @property
    def n_windows(self) -> int:
        """Number of reference windows (``Nr − L_m + 1``): the length of a score row."""
        return len(self.ref) - self.seq_len + 1

    def reset(self) -> None:
        """Forget the frames seen (e.g. at a sequence bound)."""
        self.rows.reset()

    @no_grad
    def step(self, descriptor: ArrayLike) -> torch.Tensor | None:
        """Add a query frame ``[D]``; return the scores ``[Nr − L_m + 1]`` of its window (the last L_m
        frames) against every reference window start, or None until L_m frames have been seen."""
        q = as_tensor(descriptor, self.device, "query frame", keep_float64=True).to(self.ref.dtype).reshape(-1)
        if q.shape[0] != self.ref.shape[1]:
            raise ConfigError(f"dimension mismatch: query frame D={q.shape[0]}, map D={self.ref.shape[1]}")
        if not bool(torch.isfinite(q).all()):
            raise ConfigError(f"query frame {self.count} holds NaN or inf")
        self.rows.push(self.index.distances(q[None])[0])
        if self.rows.count < self.seq_len:
            return None
        return seqmatch_window(self.rows.window(), self.reverse)

    def topk(self, scores: torch.Tensor, k: int, starts: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` best ``(scores [k], items [k])`` of a score row (among the window ``starts`` when given)."""
        sub = scores if starts is None else scores[torch.as_tensor(starts, device=scores.device)]
        v, i = topk_smallest(sub[None, :], k)
        return v[0].cpu().numpy(), i[0].cpu().numpy()
