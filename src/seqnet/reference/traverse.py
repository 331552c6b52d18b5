"""A dataset's reference traverse as a :class:`~seqnet.methods.protocol.Reference`: described on the fly."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from ..core.lazy import lazy_module
from ..core.memory import BLOCK_BYTES as MEMORY_BLOCK
from ..data.traverse import Traverse
from ..matching.hvpr import candidate_scores
from ..matching.on_disk import pair_scores_on_map
from ..matching.registry import SEQUENCE_MATCHERS
from ..methods.grammar import Method, needs
from ..search.knn import ExactIndex, knn
from ..sequence.described import Described
from ..sequence.windows import Windows

torch = lazy_module("torch")

if TYPE_CHECKING:
    from ..sequence.model import SeqNet

SHARED_BYTES = 2 * MEMORY_BLOCK  # the largest query × reference frame-distance matrix HVPR keeps to reuse


class TraverseReference:
    """The reference traverse ``traverse`` under ``windows`` (see :class:`~seqnet.methods.protocol.Reference`).

    Descriptors are computed on first use (:class:`seqnet.sequence.described.Described`) and kept
    (in temporary memory maps when large: memory stays bounded on references of any size); shortlists
    are exact k-NN (``backend``: a key of :data:`seqnet.search.knn.KNN_BACKENDS`; the
    torch index keeps the reference norms between searches).
    """

    def __init__(self, traverse: Traverse, windows: Windows, models: Mapping[str, SeqNet], device: torch.device,
                 backend: str = "torch", name: str = "reference") -> None:
        self.traverse, self.windows, self.models, self.device = traverse, windows, dict(models), device
        self.backend, self.name = backend, name
        self.described = Described(traverse.descriptors, traverse.seq_bounds, windows, self.models, device,
                                   "reference", spill=True)
        self.items, self.match_starts = self.described.side.items, self.described.side.match_starts
        self.positions, self.names = traverse.positions, traverse.names
        self.provenance, self.input_dim = traverse.provenance, traverse.dim
        self._index: dict[tuple[str, str], ExactIndex] = {}
        self.precision: torch.dtype | None = None  # half: exact searches read and multiply in it (the localiser)
        self.resident = False  # exact searches keep what they search in memory (the localiser)
        self.frame_indices = False  # query frames are descriptors
        self._starts: torch.Tensor | None = None

    def serve_online(self, precision: torch.dtype | None = None) -> None:
        """Searched frame by frame (the localiser): exact searches keep what they read resident, in ``precision``."""
        self.resident = True
        if precision is not None:
            self.precision = precision

    def check_method(self, m: Method) -> None:
        """Every method runs on a traverse (its models were checked when it was loaded)."""

    def prepare(self, m: Method) -> float:
        """Describe what ``m`` needs (its shortlist items, its frame descriptors); milliseconds."""
        return self.described.cost_ms(needs(m))

    def search(self, descriptor: str, query: torch.Tensor | np.ndarray, k: int,
               exact: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Exact k-NN over the items' ``descriptor`` (``exact`` changes nothing: the search is exact)."""
        ref = self.described.items(descriptor)
        if self.backend != "torch":
            return knn(query, ref, k, backend=self.backend, device=str(self.device))
        return self._exact(("items", descriptor), ref).search(query, k)

    def frame_distances(self, frames: str, frame: torch.Tensor) -> torch.Tensor:
        """``[Nr]`` distances of one query frame descriptor ``[D2]`` to every reference frame's ``frames``."""
        return self._exact(("frames", frames), self.described.frames(frames)).distances(frame[None])[0]

    def shared_distances(self, frames: str, query_frames: torch.Tensor | np.ndarray) -> torch.Tensor | None:
        """``[Nq, Nr]`` frame distances by ``frames`` when they fit :data:`SHARED_BYTES` (a reference in torch
        memory), else None."""
        r = self.described.frames(frames)
        if not isinstance(r, torch.Tensor) or len(query_frames) * len(r) * 4 > SHARED_BYTES:
            return None
        return self._exact(("frames", frames), r).distances(query_frames)

    def _exact(self, key: tuple[str, str], ref: torch.Tensor) -> ExactIndex:
        if key not in self._index:
            self._index[key] = ExactIndex(ref, self.device, precision=self.precision,
                                          resident=self.resident)
        return self._index[key]

    def rerank(self, frames: str, matcher: str, query_frames: torch.Tensor | np.ndarray, q_starts: np.ndarray,
               candidates: np.ndarray) -> torch.Tensor:
        """The matcher's scores of the candidates (:func:`seqnet.matching.hvpr.candidate_scores`: the query
        frames and the reference's own descriptors were checked where they were made)."""
        r = self.described.frames(frames)
        if not isinstance(r, torch.Tensor):  # spilled: read only the candidates' windows
            return pair_scores_on_map(query_frames, r, self.windows.match_len, q_starts, self.match_starts,
                                      candidates, matcher, str(self.device), anchor=self.windows.anchor)
        r = r.to(self.device)
        q = torch.as_tensor(query_frames).to(device=self.device, dtype=r.dtype)
        if self._starts is None:
            self._starts = torch.as_tensor(self.match_starts, device=self.device)
        return candidate_scores(q, r, self.windows.match_len, torch.as_tensor(q_starts, device=self.device),
                                self._starts, candidates, matcher, self.windows.anchor)

    def match(self, frames: str, matcher: str, query_frames: torch.Tensor | np.ndarray, q_starts: np.ndarray,
              k: int) -> tuple[np.ndarray, np.ndarray]:
        """The matcher over the whole traverse (its ``topk`` form)."""
        spec = SEQUENCE_MATCHERS[matcher]
        return spec.topk(query_frames, self.described.frames(frames), self.windows.match_len, k, q_starts,
                         self.match_starts, device=str(self.device), **spec.options(self.windows.anchor))

