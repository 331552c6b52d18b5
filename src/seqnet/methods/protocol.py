"""What evaluation, HVPR and the localiser need of a reference side (:class:`Reference`)."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from ..core.lazy import lazy_module
from ..sequence.windows import Windows
from .grammar import Method

torch = lazy_module("torch")


class Reference(Protocol):
    """A reference side: its items, frames, positions and names, and search / re-rank / match over them.

    Descriptor names are keys of :data:`seqnet.sequence.descriptors.SEQUENCE_DESCRIPTORS` (a map
    serves only the ones it stores: :meth:`check_method` says so first).

    Attributes:
        windows: L, L_m, window mode and anchor of the items (queries must use the same).
        items: ``[R]`` the reference frame of each item; match_starts: ``[R]`` its L_m-window start.
        positions: ``[Nr, P]`` of every reference frame; names: ``Nr`` image names or None.
        provenance: how the raw reference descriptors were made; input_dim: their D.
        device: where the computations run; name: for messages; models: its models by role (S_L, S_1).
        precision: None, or the half dtype its exact searches read and multiply in (:meth:`serve_online`).
        resident: its exact searches keep what they search in memory, whatever its size, instead of streaming a
            large one in blocks (:meth:`serve_online`: the same map searched every frame).
        frame_indices: its query frames are given as their row numbers into a distance matrix (nothing to
            describe: :class:`seqnet.reference.matrix.MatrixReference`), not as descriptors.
    """

    windows: Windows
    items: np.ndarray
    match_starts: np.ndarray
    positions: np.ndarray
    names: list[str] | None
    provenance: dict | None
    input_dim: int
    device: torch.device
    name: str
    models: dict
    precision: torch.dtype | None
    resident: bool
    frame_indices: bool


    def serve_online(self, precision: torch.dtype | None = None) -> None:
        """Be searched frame by frame from now on (the localiser): keep what the exact searches read resident, and
        read and multiply in ``precision`` (a half dtype) when given. The one way a caller changes a reference."""

    def check_method(self, m: Method) -> None:
        """Refuse a method this reference cannot run (a :class:`seqnet.core.errors.ConfigError`)."""

    def prepare(self, m: Method) -> float:
        """Describe (once) what ``m`` needs of the reference; the milliseconds spent."""

    def search(self, descriptor: str, query: torch.Tensor | np.ndarray, k: int,
               exact: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """``(distances [M, k], items [M, k])`` of the items nearest to ``query [M, D1]`` by ``descriptor``
        (exactly, or through an ANN index unless ``exact``; ``-1``: fewer found)."""

    def rerank(self, frames: str, matcher: str, query_frames: torch.Tensor | np.ndarray, q_starts: np.ndarray,
               candidates: np.ndarray) -> torch.Tensor:
        """``[M, K]`` scores of ``matcher`` on ``frames`` descriptors for the candidate items ``[M, K]``
        (``-1``: none, ``inf``) of the query windows ``q_starts [M]`` of ``query_frames [Nq, D2]``."""

    def frame_distances(self, frames: str, frame: torch.Tensor) -> torch.Tensor:
        """``[Nr]`` distances of one query frame descriptor ``frame [D2]`` to every reference frame's
        ``frames`` descriptor (the online form of the whole-map matchers reads these rows)."""

    def shared_distances(self, frames: str, query_frames: torch.Tensor | np.ndarray) -> torch.Tensor | None:
        """``[Nq, Nr]`` distances of every query frame to every reference frame by ``frames``, when they are
        cheap to hold (HVPR then reads its shortlist and its re-ranking from them), else None."""

    def match(self, frames: str, matcher: str, query_frames: torch.Tensor | np.ndarray, q_starts: np.ndarray,
              k: int) -> tuple[np.ndarray, np.ndarray]:
        """``(scores [M, k], items [M, k])``: ``matcher`` over the whole reference for the query windows."""
