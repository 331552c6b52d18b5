"""Sequence matchers as data: how a query window of frame descriptors is scored against the map.

Each :class:`SequenceMatcher` has two operations over frame descriptors ``[N, D]`` and window
starts (see :mod:`seqnet.sequence.windows`):

* ``topk(query, ref, L, k, q_starts, r_starts, device=...)`` → ``(scores [M, k], items [M, k])``:
  the whole map, keeping the k best reference items per query item;
* ``score_pairs(q, r, L, q_starts [M], cand_starts [M, K])`` → ``[M, K]`` scores of given windows
  (``-1`` = no candidate, ``inf``): the re-ranker of HVPR;
* ``window(dist [L, Nr], anchor=...)`` → ``[Nr − L + 1]``: the *online form*, the scores of one
  causal window from its L distance rows (one new row per frame: the localiser); a matcher without
  one (``online`` false) is refused there, never run as another. Equal to ``topk`` on that window
  (``tests/localize/test_parity.py``);
* ``anchored``: takes the window step pinned to the item's frame.

Matchers: ``seqmatch`` / ``seqmatch-rev`` (fixed speed, :mod:`seqnet.matching.seqmatch`), ``vseqmatch`` /
``vseqmatch-rev`` (several velocities, :mod:`seqnet.matching.velocity`), ``graph``, ``grh`` and ``grh-dh``
(paths of variable speed, :mod:`seqnet.matching.graph`; learned codes: :mod:`seqnet.matching.hashing`);
exact definitions in ``docs/matchers.md``.

Lower scores are better. Adding a matcher is one entry of :data:`SEQUENCE_MATCHERS` (method names
such as ``raw+<matcher>`` and ``hvpr-seqnet:s1+<matcher>`` follow); every fact the evaluation, the
localiser, whole-map matching on a matrix and the HVPR shortcuts read about a matcher is a field of its
entry (``diagonal``, ``reverse``, ``on_matrix``, ``online``, ``anchored``), never a second table.
docs/extending.md shows one added in a test.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import numpy as np

from ..core.lazy import lazy_module
from .graph import graph_pairs, graph_topk, grh_pairs, grh_topk
from .online import graph_window, seqmatch_window, vseqmatch_window
from .pairs import window_scores
from .seqmatch import seqmatch_topk
from .velocity import velocity_pairs, velocity_topk

torch = lazy_module("torch")


@dataclasses.dataclass(frozen=True)
class SequenceMatcher:
    """One entry of :data:`SEQUENCE_MATCHERS`."""

    name: str
    summary: str
    topk: Callable[..., tuple[np.ndarray, np.ndarray]]
    score_pairs: Callable[..., torch.Tensor]
    anchored: bool = False  # takes ``anchor=``: the window step pinned to the item's frame
    window: Callable[..., torch.Tensor] | None = None  # the online form: dist [L, Nr] of one window -> [Nr - L + 1]
    diagonal: bool = False  # one trajectory of slope 1 (or -1): scores are sums along a frame-distance diagonal
    reverse: bool = False  # the reference traversed backwards
    on_matrix: bool = False  # topk also takes a FrameDistances (a given distance matrix) as its query: --distances
    speed_robust: bool = False  # follows query and reference advancing at different rates (0.5-2x, stops)

    @property
    def online(self) -> bool:
        """Has an online form (the localiser refuses a matcher without one)."""
        return self.window is not None

    def options(self, anchor: str) -> dict[str, str]:
        """Keyword options of the matcher's functions: an anchored matcher pins step ``anchor`` of each
        window to the item's frame (:attr:`seqnet.sequence.windows.Windows.anchor`: the centre of a
        centred window, the newest frame of a causal one); the others take none."""
        return {"anchor": anchor} if self.anchored else {}


SEQUENCE_MATCHERS: dict[str, SequenceMatcher] = {
    m.name: m
    for m in (
        SequenceMatcher("seqmatch", "SeqMatch: summed distances of aligned frames (same speed, same direction)",
                        seqmatch_topk, window_scores, window=seqmatch_window, diagonal=True, on_matrix=True),
        SequenceMatcher("seqmatch-rev", "SeqMatch with the reference traversed backwards (reverse direction)",
                        functools.partial(seqmatch_topk, reverse=True), functools.partial(window_scores, reverse=True),
                        window=functools.partial(seqmatch_window, reverse=True), diagonal=True, reverse=True,
                        on_matrix=True),
        SequenceMatcher("vseqmatch", "SeqMatch over trajectories of several slopes (0.5-2 reference frames per query "
                        "frame), the best one wins", velocity_topk, velocity_pairs, anchored=True,
                        window=vseqmatch_window, on_matrix=True, speed_robust=True),
        SequenceMatcher("vseqmatch-rev", "velocity-robust SeqMatch with the reference traversed backwards",
                        functools.partial(velocity_topk, reverse=True),
                        functools.partial(velocity_pairs, reverse=True), anchored=True,
                        window=functools.partial(vseqmatch_window, reverse=True), reverse=True,
                        on_matrix=True, speed_robust=True),
        SequenceMatcher("graph", "GISM-style graph matching: cheapest path with reference steps 0..2 per query frame "
                        "(stops and speed changes)", graph_topk, graph_pairs, anchored=True, window=graph_window,
                        on_matrix=True, speed_robust=True),
        SequenceMatcher("grh", "GRH-style graph matching: paths start near FAISS LSH candidates of the first frame",
                        grh_topk, grh_pairs, anchored=True, speed_robust=True),
        SequenceMatcher("grh-dh", "GRH-style graph matching: paths start near Hamming candidates of learned binary "
                        "codes (a hashing network trained on the reference frames)",
                        functools.partial(grh_topk, codes="dh"), functools.partial(grh_pairs, codes="dh"),
                        anchored=True, speed_robust=True),
    )
}
