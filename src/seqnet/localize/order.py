"""What a sequence method's answers say about the query it was given, said after a ``seqnet localize --map`` run (one
line each, logged as a warning and kept in the track summary's ``warnings``):

* a query shorter than the method's window (:func:`short_query_note`): every answer is empty, and nothing else
  would say why;
* a query whose frames are not in capture order (:func:`order_note`): a sequence method (a window of L frames, a
  sequence matcher) assumes consecutive frames are consecutive places, so images named by a hash (as phone and
  cloud exports name them) are answered wrongly. The estimates show it: on a route they advance a few map frames
  per query frame, on a shuffled query they jump around the map (measured on 200 Nordland winter frames against
  200 summer ones, raw+seqmatch: median jump 12 frames shuffled, 1 in route order; a sequence matcher's estimates
  still advance by one frame a third of the time on a shuffled query, its windows overlapping). Estimates also
  jump on a query in order that the map does not match (a noisy one); the query's own frames tell the two apart:
  consecutive frames of a drive are more alike than distant ones, shuffled ones are not (:class:`QueryOrder`).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..methods.grammar import Method
    from .localizer import Estimate

MAP_SHARE = 0.05  # a jump bound of this share of the map's frames (at least L): a route advances far less per frame
MIN_PAIRS = 10  # fewer consecutive answered frames: too few to say anything
SAMPLE = 512  # query descriptors kept to compare consecutive frames with distant ones
ALIKE = 0.93  # consecutive frames' median distance over distant frames' above this: no more alike, not in order


def short_query_note(est: Sequence[Estimate], method: Method, name: str, window: int) -> str | None:
    """A line when the query (estimates ``est``) is shorter than ``window``, the frames the sequence method
    ``method`` (named ``name``) needs for a full window, else None (a single-frame method answers every frame)."""
    n = len(est)
    if method.single_frame or n == 0 or n >= window:
        return None
    answered = sum(e.ref_index >= 0 for e in est)
    got = "no estimate" if answered == 0 else f"{answered} estimates from partial windows only, none scored"
    return (f"{n} frames < L={window} (the window of the sequence method {name}): {got}; give at least {window} "
            "frames, or --method single")


def jumps(est: Sequence[Estimate]) -> np.ndarray:
    """``[P]`` |estimate[t+1] - estimate[t]| in map frames over consecutive frames that both have an estimate."""
    f = np.array([e.ref_frame for e in est], dtype=np.int64)
    both = (f[1:] >= 0) & (f[:-1] >= 0)
    return np.abs(np.diff(f))[both]


class QueryOrder:
    """Keeps the first :data:`SAMPLE` query descriptors of a stream (:meth:`watch`) to tell a query in capture
    order (consecutive frames alike: consecutive places) from one whose order is lost (:meth:`looks_ordered`)."""

    def __init__(self) -> None:
        self.sample: list[np.ndarray] = []

    def watch(self, frames: Iterator[tuple[np.ndarray, float]]) -> Iterator[tuple[np.ndarray, float]]:
        """``frames`` as they are, the first :data:`SAMPLE` descriptors kept (copied, as float32)."""
        for d, ms in frames:
            if len(self.sample) < SAMPLE:
                self.sample.append(np.array(d, dtype=np.float32, copy=True).reshape(-1))
            yield d, ms

    def alike(self) -> float | None:
        """The median distance of consecutive sampled frames over that of frames half the sample apart (about 0.8
        on a drive's frames, about 1 shuffled: 0.78 / 0.99 on 200 Nordland winter frames); None with fewer than
        :data:`MIN_PAIRS` frames."""
        n = len(self.sample)
        if n < MIN_PAIRS:
            return None
        x = np.stack(self.sample).astype(np.float64)
        near = np.median(np.linalg.norm(x[1:] - x[:-1], axis=1))
        far = np.median(np.linalg.norm(x - np.roll(x, n // 2, axis=0), axis=1))
        return None if far <= 0 else float(near / far)

    def looks_ordered(self) -> bool:
        """Whether consecutive sampled frames are more alike than distant ones (or too few to tell)."""
        ratio = self.alike()
        return ratio is None or ratio <= ALIKE


def order_note(est: Sequence[Estimate], method: Method, window: int, map_frames: int,
               query: QueryOrder | None = None) -> str | None:
    """A line when the estimates ``est`` of a sequence method ``method`` (window L = ``window``) jump around the
    map of ``map_frames`` frames far more than a route would (the median |jump| between consecutive estimates over
    max(L, :data:`MAP_SHARE` of the map)) and the query's consecutive frames are no more alike than distant ones
    (``query``, :meth:`QueryOrder.looks_ordered`; estimates that jump on a query in order are a map that does not
    match it, not an order lost): the query frames are probably not in capture order. None otherwise, for a
    single-frame method (order is nothing to it), and with fewer than :data:`MIN_PAIRS` pairs."""
    if method.single_frame:
        return None
    d = jumps(est)
    if len(d) < MIN_PAIRS:
        return None
    bound = max(int(window), int(np.ceil(MAP_SHARE * map_frames)))
    median = float(np.median(d))
    if median <= bound or (query is not None and query.looks_ordered()):
        return None
    return (f"consecutive estimates jump around the map: median jump {median:g} frames of a map of {map_frames} "
            f"(a route advances a few; bound {bound}), and consecutive query frames are no more alike than distant "
            "ones: a sequence method assumes the query frames are in capture order, are they? hint: give the images "
            "in capture order (a list file, or names that sort in capture order: ls -v), or use a single-frame "
            "method (--method single)")
