"""The descriptors of one evaluation: evaluated items, their windows, and every descriptor, computed once.

An *item* is a frame whose windows fit inside its sequence: the L-frame window of the sequence
descriptors and the L_m-frame window of the sequence matchers (both centred, or both causal). The
same items are used for every method, so numbers are comparable.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping

import numpy as np
import torch

from ..core.errors import ConfigError
from ..data.traverse import Traverse
from ..sequence.descriptors import SEQUENCE_DESCRIPTORS, SeqNet, describe_windows
from ..sequence.windows import window_frames, window_indices, window_starts


@dataclasses.dataclass
class Side:
    """The evaluated items of one traverse.

    Attributes:
        traverse: the traverse.
        items: ``[M]`` frame index of each item (the frame whose windows fit).
        starts: ``[M]`` first frame of each item's L-frame descriptor window.
        match_starts: ``[M]`` first frame of each item's L_m-frame matching window.
    """

    traverse: Traverse
    items: np.ndarray
    starts: np.ndarray
    match_starts: np.ndarray

    @classmethod
    def of(cls, t: Traverse, seq_len: int, match_len: int, mode: str) -> Side:
        """Items of ``t`` whose L-window and L_m-window both fit inside their sequence."""
        starts, ok = window_starts(len(t), seq_len, mode, t.seq_bounds)
        m_starts, m_ok = window_starts(len(t), match_len, mode, t.seq_bounds)
        items = np.flatnonzero(ok & m_ok)
        return cls(t, items, starts[items], m_starts[items])


class Descriptors:
    """Query and reference descriptors of one evaluation, each computed once and timed (ms).

    ``items(name)`` gives the sequence descriptor ``name`` (a key of :data:`SEQUENCE_DESCRIPTORS`)
    of every item, ``[M, D']`` / ``[R, D']``; ``frames(name)`` the same descriptor over every
    frame's window (clamped at sequence bounds), ``[Nq, D']`` / ``[Nr, D']``, for the matchers.
    """

    def __init__(self, query: Side, reference: Side, seq_len: int, mode: str, models: Mapping[str, SeqNet],
                 device: torch.device):
        if len(query.items) == 0 or len(reference.items) == 0:
            side = "query" if len(query.items) == 0 else "reference"
            raise ConfigError(f"no {side} frame has a full window of seq_len={seq_len} inside its sequence; "
                              "use a shorter --seq-len")
        self.query, self.reference, self.seq_len, self.mode = query, reference, seq_len, mode
        self.models, self.device = models, device
        self._cache: dict[tuple[str, str], tuple[torch.Tensor, torch.Tensor]] = {}
        self.ms: dict[tuple[str, str], float] = {}

    def items(self, name: str) -> tuple[torch.Tensor, torch.Tensor]:
        """``(query [M, D'], reference [R, D'])`` item descriptors ``name``."""
        return self._get("items", name)

    def frames(self, name: str) -> tuple[torch.Tensor, torch.Tensor]:
        """``(query [Nq, D'], reference [Nr, D'])`` frame descriptors ``name``."""
        return self._get("frames", name)

    def time_ms(self, kind: str, name: str) -> float:
        """Milliseconds spent on ``kind`` ("items" / "frames") descriptors ``name``, dependencies included."""
        self._get(kind, name)
        return self.ms[(kind, name)]

    def _get(self, kind: str, name: str) -> tuple[torch.Tensor, torch.Tensor]:
        key = (kind, name)
        if key not in self._cache:
            # items of a single-frame descriptor index its frame descriptors: their time counts too
            dep = ("frames", name) if kind == "items" and SEQUENCE_DESCRIPTORS[name].single_frame else None
            if dep is not None:
                self._get(*dep)
            t0 = time.perf_counter()
            self._cache[key] = self._compute(kind, name)
            self.ms[key] = (time.perf_counter() - t0) * 1e3 + (self.ms[dep] if dep else 0.0)
        return self._cache[key]

    def _compute(self, kind: str, name: str) -> tuple[torch.Tensor, torch.Tensor]:
        d = SEQUENCE_DESCRIPTORS[name]
        fn = d.window_fn(self.models)
        if kind == "items" and d.single_frame:  # the frame's own descriptor: index the frame descriptors
            fq, fr = self.frames(name)
            return fq[self.query.items], fr[self.reference.items]
        out = []
        for side in (self.query, self.reference):
            t = side.traverse
            if kind == "frames":
                idx = window_indices(len(t), d.length(self.seq_len), self.mode, t.seq_bounds)
            else:
                idx = window_frames(side.starts, self.seq_len)
            out.append(describe_windows(t.descriptors, idx, fn, device=self.device, progress=name))
        return out[0], out[1]
