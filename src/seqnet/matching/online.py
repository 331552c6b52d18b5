"""Incremental sequence matching for a query stream (a robot localising frame by frame).

:class:`Ring`: the last ``n`` rows of a stream as one contiguous view (the localiser's recent frames,
frame descriptors and distance rows: one new row per frame, the window's scores then ``L_m`` shifted
adds). The window forms (``seqmatch_window``, ``vseqmatch_window``, ``graph_window``:
the L_m distance rows of a causal window → its scores against every reference window start) are
the *online form* column of :data:`seqnet.matching.registry.SEQUENCE_MATCHERS`.
"""

from __future__ import annotations

import functools

from ..core.errors import ConfigError
from ..core.lazy import lazy_module
from ..sequence.windows import check_seq_len
from .banded import shifted_sum
from .graph import DEFAULT_FAN_OUT
from .paths import path_dp
from .velocity import DEFAULT_VELOCITIES, pivot_step, trajectories, velocity_block

torch = lazy_module("torch")


class Ring:
    """The last ``n`` rows ``[W]`` pushed, readable as one contiguous ``[min(count, n), W]`` view, oldest first.

    Each row is written twice (at ``i`` and ``i + n`` of a ``[2n, W]`` buffer), so the window is a
    slice: no copy, no reordering.
    """

    def __init__(self, n: int, width: int, dtype: torch.dtype, device: torch.device) -> None:
        self.n = check_seq_len(n, None, "ring length")
        self.buf = torch.zeros((2 * self.n, width), dtype=dtype, device=device)
        self.count = 0  # rows pushed since the last reset

    def reset(self) -> None:
        """Forget every row."""
        self.count = 0

    def push(self, row: torch.Tensor) -> None:
        """Append ``row [W]`` (the oldest row drops out once ``n`` are held)."""
        i = self.count % self.n
        self.buf[i] = row
        self.buf[i + self.n] = row
        self.count += 1

    def window(self) -> torch.Tensor:
        """``[min(count, n), W]``: the rows held, oldest first (a view)."""
        if self.count < self.n:
            return self.buf[: self.count]
        i = self.count % self.n
        return self.buf[i : i + self.n]


def seqmatch_window(dist: torch.Tensor, reverse: bool = False, anchor: str = "centre") -> torch.Tensor:
    """SeqMatch scores ``[Nr − L + 1]`` of the window whose ``L`` distance rows are ``dist [L, Nr]``
    (``anchor`` is ignored: a fixed-speed window has one alignment)."""
    seq_len = dist.shape[0]
    nb = dist.shape[1] - seq_len + 1
    cols = [(seq_len - 1 - t) if reverse else t for t in range(seq_len)]
    return shifted_sum(dist, 0, 1, cols, nb, dist.new_empty((1, nb)))[0]


def vseqmatch_window(dist: torch.Tensor, reverse: bool = False, anchor: str = "centre") -> torch.Tensor:
    """Velocity-robust SeqMatch scores ``[Nr − L + 1]`` of one window
    (:func:`seqnet.matching.velocity.velocity_block`)."""
    seq_len = dist.shape[0]
    trajs = _trajectories(seq_len, anchor, reverse)
    return velocity_block(dist, 0, 1, trajs, dist.shape[1] - seq_len + 1)[0]


@functools.lru_cache(maxsize=32)
def _trajectories(seq_len: int, anchor: str, reverse: bool) -> list[tuple[int, ...]]:
    return trajectories(DEFAULT_VELOCITIES, seq_len, anchor, reverse)


def graph_window(dist: torch.Tensor, reverse: bool = False, anchor: str = "centre") -> torch.Tensor:
    """Graph-matching scores ``[Nr − L + 1]`` of one window: the cheapest path through frame ``b + p``
    (:func:`seqnet.matching.graph.path_dp`, ``fan_out`` 2)."""
    if reverse:
        raise ConfigError("graph matching has no reverse form")
    seq_len = dist.shape[0]
    p = pivot_step(anchor, seq_len)
    costs = path_dp(lambda t: dist[t : t + 1], seq_len, DEFAULT_FAN_OUT, p)[0]
    return costs[p : p + dist.shape[1] - seq_len + 1]
