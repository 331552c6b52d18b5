"""A dataset's reference traverse for the model-free k-NN methods, in numpy: :class:`PlainReference` (no torch).

``seqnet eval --method single`` (and ``smoothing``, ``delta``, ``delta-paper``) on descriptor files is what a
user runs first to score descriptors; it needs neither a model nor a matcher, so it runs without torch: the
descriptors are :class:`seqnet.sequence.npdescribed.PlainDescribed`, the search
:class:`seqnet.search.npexact.NumpyExactIndex` (the answers of the torch index, its checks kept).
:func:`runs_plain` says when an evaluation takes this path; every other one takes
:class:`seqnet.reference.traverse.TraverseReference`.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Mapping, Sequence

import numpy as np

from ..core.errors import ConfigError
from ..data.traverse import Traverse
from ..methods.grammar import Method, needs
from ..search.npexact import NumpyExactIndex
from ..sequence.npdescribed import PLAIN_DESCRIPTORS, PlainDescribed, inverse_norms
from ..sequence.windows import Windows

NVIDIA_NODES = ("/dev/nvidiactl", "/proc/driver/nvidia/version")  # a CUDA machine, seen without loading torch


def cuda_maybe() -> bool:
    """Whether ``--device auto`` could mean CUDA here: torch (when loaded already) says so, else an NVIDIA driver
    is present."""
    torch = sys.modules.get("torch")
    if torch is not None:
        return bool(torch.cuda.is_available())
    return any(os.path.exists(p) for p in NVIDIA_NODES)


def runs_plain(methods: Sequence[Method], models: Mapping[str, object] | None, backend: str, device: str) -> bool:
    """Whether the evaluation of ``methods`` runs on :class:`PlainReference`: every method a k-NN on a model-free
    descriptor, no model given, the default (torch) backend, on the CPU (``cpu``, or ``auto`` without CUDA)."""
    plain = all(m.kind == "knn" and m.shortlist in PLAIN_DESCRIPTORS for m in methods)
    cpu = device == "cpu" or (device == "auto" and not cuda_maybe())
    return bool(methods) and plain and not models and backend == "torch" and cpu


class PlainReference:
    """The reference traverse ``traverse`` under ``windows`` for model-free k-NN methods (see the module and
    :class:`~seqnet.methods.protocol.Reference`; searches only)."""

    def __init__(self, traverse: Traverse, windows: Windows, name: str = "reference") -> None:
        self.traverse, self.windows, self.name = traverse, windows, name
        self.described = PlainDescribed(traverse.descriptors, traverse.seq_bounds, windows, "reference", spill=True)
        self.items, self.match_starts = self.described.side.items, self.described.side.match_starts
        self.positions, self.names = traverse.positions, traverse.names
        self.provenance, self.input_dim = traverse.provenance, traverse.dim
        self.device, self.models, self.precision, self.resident, self.frame_indices = "cpu", {}, None, False, False
        self._index: dict[str, NumpyExactIndex] = {}
        self._scaled_index: NumpyExactIndex | None | bool = False  # not made yet
        self._scaled_ms = 0.0

    def check_method(self, m: Method) -> None:
        """Only k-NN on a model-free descriptor."""
        if m.kind != "knn" or m.shortlist not in PLAIN_DESCRIPTORS:
            raise ConfigError(f"method {m.name!r} is not a model-free k-NN method ({', '.join(PLAIN_DESCRIPTORS)})")

    def prepare(self, m: Method) -> float:
        """Describe the items ``m`` searches (``single`` on every frame: their inverse norms only); milliseconds."""
        if m.shortlist == "single" and self._scaled() is not None:
            return self._scaled_ms
        return self.described.cost_ms(needs(m))

    def search(self, descriptor: str, query: np.ndarray, k: int, exact: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Exact k-NN over the items' ``descriptor`` (``exact`` changes nothing: the search is exact)."""
        if descriptor not in self._index:
            scaled = self._scaled() if descriptor == "single" else None
            self._index[descriptor] = scaled or NumpyExactIndex(self.described.items(descriptor))
        return self._index[descriptor].search(np.asarray(query), k)

    def _scaled(self) -> NumpyExactIndex | None:
        """``single`` over every reference frame as the file's rows scaled by their inverse norms (no normalised
        copy of the reference: :func:`seqnet.sequence.npdescribed.inverse_norms`), float32 as the described rows
        are; None when the items are not every frame or a norm is out of range."""
        if self._scaled_index is False:
            t0, raw, self._scaled_index = time.perf_counter(), self.traverse.descriptors, None
            if len(self.items) == len(raw) and bool((self.items == np.arange(len(raw))).all()):
                inv = inverse_norms(raw)
                if inv is not None:
                    self._scaled_index = NumpyExactIndex(raw, row_scale=inv, dtype=np.float32)
            self._scaled_ms = (time.perf_counter() - t0) * 1e3
        return self._scaled_index
