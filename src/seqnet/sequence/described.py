"""Describing a traverse: the sequence descriptors of its items and of its frames, computed once and timed.

The one implementation of "describe a traverse": the evaluation's query side, a dataset's
reference side (:class:`seqnet.reference.TraverseReference`), a map being built and a map's
queries all use :class:`Described`; the online localiser describes its newest frame with the same
two functions, :func:`describe_frames` and :func:`describe_items`, on its ring of recent frames.

* ``items(name)``: the descriptor ``name`` (a key of :data:`SEQUENCE_DESCRIPTORS`) of every item's
  L-window, ``[M, D']`` (a single-frame descriptor: the item's own frame);
* ``frames(name)``: the descriptor over every frame's window (clamped at sequence bounds),
  ``[N, D']``, for the sequence matchers.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from ..core.lazy import lazy_module
from ..core.memmaps import take_rows
from .descriptors import SEQUENCE_DESCRIPTORS, describe_windows
from .windows import WindowedItems, Windows, window_frames, window_indices

torch = lazy_module("torch")

if TYPE_CHECKING:
    from .model import SeqNet


def describe_frames(raw: np.ndarray | torch.Tensor, seq_bounds: np.ndarray | None, name: str, windows: Windows,
                    models: Mapping[str, SeqNet], device: torch.device, which: np.ndarray | None = None,
                    progress: str | None = None, spill: bool = False) -> torch.Tensor | np.ndarray:
    """``[N', D']``: descriptor ``name`` over the window of every frame of ``raw [N, D]`` (or of the frames
    ``which``), windows of ``windows.mode`` clamped into their sequence (``spill``: a large result is a
    temporary memory map, :func:`seqnet.sequence.descriptors.describe_windows`)."""
    d = SEQUENCE_DESCRIPTORS[name]
    length = d.length(windows.seq_len)
    if length == 1 and which is not None:  # a frame's own descriptor: its window is the frame itself
        idx = np.asarray(which, dtype=np.int64)[:, None]
    else:
        idx = window_indices(len(raw), length, windows.mode, seq_bounds)
        idx = idx if which is None else idx[which]
    return describe_windows(raw, idx, d.window_fn(models), device=device, progress=progress, spill=spill)


def describe_items(raw: np.ndarray | torch.Tensor, starts: np.ndarray, name: str, windows: Windows,
                   models: Mapping[str, SeqNet], device: torch.device, progress: str | None = None,
                   spill: bool = False) -> torch.Tensor | np.ndarray:
    """``[M, D']``: descriptor ``name`` (not single-frame) of the L-windows starting at ``starts [M]``."""
    d = SEQUENCE_DESCRIPTORS[name]
    return describe_windows(raw, window_frames(starts, windows.seq_len), d.window_fn(models), device=device,
                            progress=progress, spill=spill)


class Described(WindowedItems):
    """One traverse's items under ``windows`` and its descriptors, each computed once and timed (ms).

    Args:
        descriptors: ``[N, D]`` single-image descriptors (numpy, memory map or tensor).
        seq_bounds: ``[N, 2]`` sequence range of every frame, or None.
        windows: L, L_m and the window mode; models: trained models by role; device: where to compute.
        what: ``"query"`` or ``"reference"`` (for errors).
        spill: descriptors over :data:`seqnet.core.memmaps.SPILL_BYTES` are kept in temporary memory maps
            (:class:`seqnet.core.memmaps.Spilled`, read in blocks) instead of torch memory: a reference side.
    """

    def __init__(self, descriptors: np.ndarray | torch.Tensor, seq_bounds: np.ndarray | None, windows: Windows,
                 models: Mapping[str, SeqNet], device: torch.device, what: str = "query", spill: bool = False) -> None:
        self.raw, self.seq_bounds, self.windows = descriptors, seq_bounds, windows
        self.models, self.device, self.spill = models, device, spill
        self._set_side(windows, len(descriptors), seq_bounds, what)
        self._cache: dict[tuple[str, str], torch.Tensor] = {}
        self.ms: dict[tuple[str, str], float] = {}

    def items(self, name: str) -> torch.Tensor | np.ndarray:
        """``[M, D']`` item descriptors ``name`` (a tensor, or a :class:`~seqnet.core.memmaps.Spilled` map)."""
        return self._get("items", name)

    def frames(self, name: str) -> torch.Tensor | np.ndarray:
        """``[N, D']`` frame descriptors ``name`` (a tensor, or a :class:`~seqnet.core.memmaps.Spilled` map)."""
        return self._get("frames", name)

    def time_ms(self, kind: str, name: str) -> float:
        """Milliseconds spent on ``kind`` (``"items"`` / ``"frames"``) descriptors ``name``, dependencies included."""
        return self.cost_ms([(kind, name)])

    def cost_ms(self, keys: list[tuple[str, str]]) -> float:
        """Milliseconds spent on the descriptors ``keys`` (``(kind, name)`` pairs), each computation counted once
        (the items of a single-frame descriptor index its frames: those count once for both)."""
        done = set()
        for kind, name in keys:
            self._get(kind, name)
            done |= {(kind, name), *self._deps(kind, name)}
        return sum(self.ms[k] for k in done)

    @staticmethod
    def _deps(kind: str, name: str) -> list[tuple[str, str]]:
        return [("frames", name)] if kind == "items" and SEQUENCE_DESCRIPTORS[name].single_frame else []

    def _get(self, kind: str, name: str) -> torch.Tensor | np.ndarray:
        key = (kind, name)
        if key not in self._cache:
            # items of a single-frame descriptor index its frame descriptors: their time counts too
            dep = ("frames", name) if kind == "items" and SEQUENCE_DESCRIPTORS[name].single_frame else None
            if dep is not None:
                self._get(*dep)
            t0 = time.perf_counter()
            if dep is not None:
                frames = self._cache[dep]
                self._cache[key] = (frames[self.side.items] if isinstance(frames, torch.Tensor)
                                    else take_rows(frames, self.side.items, spill=True))
            elif kind == "frames":
                self._cache[key] = describe_frames(self.raw, self.seq_bounds, name, self.windows, self.models,
                                                   self.device, progress=name, spill=self.spill)
            else:
                self._cache[key] = describe_items(self.raw, self.side.starts, name, self.windows, self.models,
                                                  self.device, progress=name, spill=self.spill)
            self.ms[key] = (time.perf_counter() - t0) * 1e3
        return self._cache[key]
