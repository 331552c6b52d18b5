"""A reference side given as a precomputed ``[Nq, Nr]`` frame-distance matrix (VPR-Bench, VPR_Tutorial, any tool).

Evaluation runs its one loop (:func:`seqnet.eval.runner.run`) on a :class:`MatrixReference` and a
:class:`MatrixQuery`: the frame "descriptors" are the frames' indices into the matrix, k-NN reads a
row, SeqMatch re-ranks candidates from its diagonals (:func:`seqnet.matching.pairs.item_scores_from_distances`)
and HVPR shortlists and re-ranks from the same matrix (``shared_distances``); whole-map matching runs each
matcher's block function on blocks of its rows (:class:`seqnet.matching.velocity.FrameDistances`; SeqMatch
as the slope-1 trajectory).
The methods are the ones that read single-frame distances (:func:`matrix_methods`); anything that
needs descriptors (sequence descriptors, models, GRH's LSH codes) is refused.

Query frames are given as their row numbers (``[M, 1]``): the whole query offline, the frames of the
newest window online (``seqnet localize --distances``, :attr:`MatrixReference.frame_indices`), so window
starts relative to the frames given are turned into rows here, and online equals offline causal.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError
from ..core.lazy import lazy_module
from ..data.traverse import Traverse
from ..matching.pairs import item_scores_from_distances, nearest_items
from ..matching.registry import SEQUENCE_MATCHERS
from ..matching.velocity import FrameDistances, velocity_topk
from ..methods.grammar import Method
from ..search.given import GivenMatrix
from ..search.nptopk import topk_smallest_np
from ..sequence.windows import Windows

torch = lazy_module("torch")


def matrix_methods() -> tuple[str, ...]:
    """The methods that run on a distance matrix, read off the matcher table: ``single``, ``raw+<m>`` for every
    matcher whose whole-map form takes the matrix (``on_matrix``), HVPR re-ranking with a diagonal one."""
    return ("single", *(f"raw+{n}" for n, m in SEQUENCE_MATCHERS.items() if m.on_matrix),
            *(f"hvpr-single:raw+{n}" for n, m in SEQUENCE_MATCHERS.items() if m.diagonal))


def frame_indices(n: int) -> torch.Tensor:
    """``[n, 1]``: frames as their own row / column of the matrix (the "descriptors" of a matrix side)."""
    return torch.arange(n, dtype=torch.float64)[:, None]


def frame_rows(n: int) -> np.ndarray:
    """:func:`frame_indices` as numpy (a query side that needs no torch)."""
    return np.arange(n, dtype=np.float64)[:, None]


class MatrixQuery:
    """The query side of a distance matrix: its items under ``windows`` (see :class:`seqnet.methods.rank.Query`)."""

    def __init__(self, n: int, seq_bounds: np.ndarray | None, windows: Windows) -> None:
        self.side = windows.side(n, seq_bounds)
        if len(self.side.items) == 0:
            raise ConfigError(f"no query frame has a full window of seq_len={windows.seq_len} (L_m={windows.match_len})"
                              f"; use a shorter {windows.longest_option}")
        self.match_starts, self.items_index, self.n = self.side.match_starts, self.side.items, n
        self.seq_bounds = seq_bounds

    def items(self, name: str) -> np.ndarray:
        return frame_rows(self.n)[self.side.items]

    def frames(self, name: str) -> np.ndarray:
        return frame_rows(self.n)

    def cost_ms(self, keys: list[tuple[str, str]]) -> float:
        return 0.0


class MatrixReference:
    """The reference traverse ``traverse`` seen through ``dist [Nq, Nr]`` (lower is closer; see the module): a
    tensor, or a :class:`seqnet.search.given.GivenMatrix` (read block by block in numpy by :meth:`search`; made a
    float64 tensor only when a method reads more than its nearest frames)."""

    def __init__(self, dist: torch.Tensor | GivenMatrix, traverse: Traverse, windows: Windows,
                 name: str = "reference") -> None:
        if dist.ndim != 2 or dist.shape[1] != len(traverse):
            raise ConfigError(f"the distance matrix must be [N_query, {len(traverse)}], got {tuple(dist.shape)}")
        self.given = dist if isinstance(dist, GivenMatrix) else None
        self._dist = None if self.given is not None else dist
        self.windows, self.name = windows, name
        side = windows.side(len(traverse), traverse.seq_bounds)
        self.items, self.match_starts = side.items, side.match_starts
        self.positions, self.names, self.provenance = traverse.positions, traverse.names, None
        self.input_dim, self.device, self.models = 1, "cpu", {}
        self.frame_indices = True  # a query frame is its row number: the localiser streams rows, describes nothing
        self.precision, self.resident = None, True

    @property
    def dist(self) -> torch.Tensor:
        """The ``[Nq, Nr]`` distances as a tensor (a given matrix made one, float64, on first use)."""
        if self._dist is None:
            self._dist = torch.as_tensor(self.given.dense())
        return self._dist

    def serve_online(self, precision: torch.dtype | None = None) -> None:
        """A matrix is resident already and holds distances, not descriptors: no precision to choose."""
        if precision is not None:
            raise ConfigError("--precision applies to descriptors; a distance matrix is read as it is given")

    def check_method(self, m: Method) -> None:
        """Only methods that read single-frame distances run on a matrix."""
        spec = SEQUENCE_MATCHERS.get(m.matcher) if m.matcher else None
        fits = spec is None or (spec.on_matrix if m.kind == "match" else spec.diagonal)
        ok = (m.shortlist in (None, "single") and m.frames in (None, "raw") and not m.fused and fits
              and m.models() == set())
        if not ok:
            raise ConfigError(f"method {m.name!r} needs descriptors; on a distance matrix: "
                              f"{', '.join(matrix_methods())}")

    def prepare(self, m: Method) -> float:
        return 0.0

    def search(self, descriptor: str, query: torch.Tensor, k: int,
               exact: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """The k nearest items of the query frames ``query [M, 1]`` (their rows)."""
        if self._dist is not None:
            return nearest_items(self.dist, torch.as_tensor(query)[:, 0], self.items, k)
        rows = np.asarray(query)[:, 0].astype(np.int64)
        every = len(self.items) == self.given.shape[1] and bool((self.items == np.arange(len(self.items))).all())
        if every and len(rows) == self.given.shape[0] and bool((rows == np.arange(len(rows))).all()):
            return self.given.scan(k).topk  # every row against every frame: the one pass over the file
        return _nearest(self.given, rows, self.items, k)

    def shared_distances(self, frames: str, query_frames: torch.Tensor) -> torch.Tensor:
        """The rows of the query frames given (the matrix itself when they are all its rows, in order)."""
        rows = _rows(query_frames)
        if len(rows) == self.dist.shape[0] and bool((rows == torch.arange(len(rows))).all()):
            return self.dist
        return self.dist[rows]

    def rerank(self, frames: str, matcher: str, query_frames: torch.Tensor, q_starts: np.ndarray,
               candidates: np.ndarray) -> torch.Tensor:
        """SeqMatch of the candidate items ``[M, K]`` (``-1``: none) read from the matrix."""
        return item_scores_from_distances(self.dist, self.windows.match_len, _rows(query_frames)[q_starts],
                                          torch.as_tensor(self.match_starts), candidates,
                                          SEQUENCE_MATCHERS[matcher].reverse)

    def match(self, frames: str, matcher: str, query_frames: torch.Tensor, q_starts: np.ndarray,
              k: int) -> tuple[np.ndarray, np.ndarray]:
        """Whole-map matching over the matrix: every matcher's block function on blocks of the matrix's rows
        (memory bounded: no ``[M, R, L]`` gather), the k best kept."""
        rows = _rows(query_frames)[q_starts].numpy()
        if SEQUENCE_MATCHERS[matcher].diagonal:  # SeqMatch is the one trajectory of slope 1 (reverse: -1)
            topk, opts = velocity_topk, {"velocities": (1.0,), "reverse": SEQUENCE_MATCHERS[matcher].reverse}
        else:
            topk, opts = SEQUENCE_MATCHERS[matcher].topk, SEQUENCE_MATCHERS[matcher].options(self.windows.anchor)
        return topk(FrameDistances(self.dist), None, self.windows.match_len, k, rows, self.match_starts, device="cpu",
                    **opts)

    def frame_distances(self, frames: str, frame: torch.Tensor) -> torch.Tensor:
        """``[Nr]``: the matrix row of one query frame (``frame [1]``: its row number)."""
        return self.dist[int(frame[0])]


def _nearest(given: GivenMatrix, rows: np.ndarray, items: np.ndarray, k: int,
             block: int = 1024) -> tuple[np.ndarray, np.ndarray]:
    """``(distances [M, k], items [M, k])`` of the query frames ``rows [M]`` among ``items`` (in blocks of rows):
    :func:`seqnet.matching.pairs.nearest_items` on a given matrix, without torch."""
    k = min(k, len(items))
    out = [topk_smallest_np(given[np.ix_(rows[a:a + block], items)], k) for a in range(0, len(rows), block)]
    if not out:
        return np.zeros((0, k)), np.zeros((0, k), np.int64)
    return np.concatenate([v for v, _ in out]), np.concatenate([i for _, i in out])


def _rows(query_frames: torch.Tensor | np.ndarray) -> torch.Tensor:
    """The matrix rows (int64 ``[M]``) of query frames given as row numbers ``[M, 1]``."""
    return torch.as_tensor(query_frames)[:, 0].long()
