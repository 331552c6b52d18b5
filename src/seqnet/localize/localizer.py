"""Online localisation: one answer per query frame from causal windows, with a latency and a confidence.

:class:`Localizer` answers ``.step(descriptor [D]) -> Estimate`` for a stream of query frames with
any method of :mod:`seqnet.eval.methods` (``single``, ``s1``, ``seqnet``, ``<frames>+<matcher>``,
``hvpr-…``). Per frame, after a one-time description of the map's reference frames and items:

* the raw frame joins a ring buffer of the last L frames (:class:`seqnet.matching.online.Ring`);
* frame-descriptor methods (``<frames>+<matcher>``, HVPR) describe the new frame once (its own
  descriptor, S_1, or a sequence descriptor of its L-frame window) into a ring of the last L_m
  frame descriptors; whole-map matchers add the frame's distance row to the map (one GEMV) to a ring
  of L_m rows and score the latest window from them (:data:`seqnet.matching.online.WINDOW_MATCHERS`);
* k-NN methods and HVPR shortlists describe the latest L-frame window (e.g. S_L) and compare it with
  the map's reference items (one GEMV); HVPR re-ranks the top K with the matcher's pair scores.

**Equal to the offline evaluation.** Reference items are the map frames whose causal L- and
L_m-windows fit inside their sequence (:class:`seqnet.eval.features.Side`, ``"causal"``). A query
frame whose L- and L_m-windows since the last :meth:`Localizer.reset` are full
(``Estimate.full_window``) is exactly an item of ``evaluate(ds, EvalConfig(window="causal"))``,
and its ranking, scores and confidence equal that evaluation's (up to float rounding) with the
default anchor ``"end"``: like the evaluation of causal windows, the variable-speed matchers pin the
newest query frame to the item's frame (see docs/online.md). Earlier frames are answered as soon
as the method's own windows are full (from the first frame for single-frame k-NN), else not at all
(``ref_index = -1``).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator, Mapping
from typing import Protocol

import numpy as np
import torch

from ..core.config import check_choice
from ..core.errors import ConfigError
from ..core.utils import ArrayLike, as_tensor, get_device
from ..data.traverse import Dataset, Traverse
from ..eval.checks import check_inputs
from ..eval.evaluate import EvalConfig
from ..eval.features import Side
from ..eval.methods import FRAME_FEATURES, parse_method
from ..eval.metrics.precision_recall import ratio_confidence
from ..matching.online import WINDOW_MATCHERS, Ring, distance_row
from ..matching.velocity import ANCHORS
from ..search.blocks import topk_smallest
from ..search.knn import sq_norms
from ..sequence.descriptors import SEQUENCE_DESCRIPTORS, SeqNet, describe_windows
from ..sequence.windows import window_frames, window_indices


class MapLike(Protocol):
    """What a :class:`Localizer` needs of a map: the reference traverse (descriptors ``[Nr, D]``,
    positions, names, sequence bounds, provenance), the localisation radius (for the confidence) and
    the trained models by role (``"seqnet"``: S_L, ``"s1"``: S_1)."""

    reference: Traverse
    radius: float
    models: Mapping[str, SeqNet]


@dataclasses.dataclass
class ReferenceMap:
    """A map made from a dataset's reference traverse (see :class:`MapLike`)."""

    reference: Traverse
    radius: float
    models: Mapping[str, SeqNet] = dataclasses.field(default_factory=dict)
    name: str = "map"

    @classmethod
    def from_dataset(cls, ds: Dataset, models: Mapping[str, SeqNet] | None = None) -> ReferenceMap:
        """The reference traverse of ``ds`` (already restricted to a split) with its radius."""
        return cls(ds.reference, ds.radius, dict(models or {}), ds.name)

    @property
    def provenance(self) -> dict | None:
        """How the reference descriptors were made."""
        return self.reference.provenance

    @property
    def names(self) -> list[str] | None:
        """The reference frames' image names."""
        return self.reference.names


@dataclasses.dataclass
class Estimate:
    """The answer for one query frame.

    Attributes:
        frame: index of the query frame in the stream (counted across resets).
        ref_index: the best reference item (index into :attr:`Localizer.ref_items`), -1 = no answer.
        ref_frame: its frame in the map's reference traverse, -1 = no answer.
        score: its score (lower is better; nan without an answer).
        confidence: ratio confidence in [0, 1] (:func:`seqnet.eval.metrics.precision_recall.ratio_confidence`).
        latency_ms: time spent in :meth:`Localizer.step`.
        full_window: the L- and L_m-windows since the last reset are full (an evaluation item).
        ranked, scores: ``[k]`` reference items best first and their scores (``inf``: not scored).
    """

    frame: int
    ref_index: int
    ref_frame: int
    score: float
    confidence: float
    latency_ms: float
    full_window: bool
    ranked: np.ndarray
    scores: np.ndarray


class Localizer:
    """Frame-by-frame localisation against a map (see the module docstring).

    Args:
        ref_map: the map (:class:`MapLike`, e.g. :meth:`ReferenceMap.from_dataset`).
        method: a method name (:mod:`seqnet.eval.methods`); ``grh`` has no online form.
        conf: lengths L (``seq_len``; default the S_L model's) and L_m (``rerank_seq_len``), the HVPR
            shortlist ``top_k``, the ranking length ``max(ks)``, ``device``, ``allow_mismatch``;
            ``window`` is always causal.
        anchor: pivot step of the variable-speed matchers (``"end"``: the newest frame, as the evaluation of
            causal windows; ``"centre"`` / ``"start"``: another step of the window).
    """

    def __init__(self, ref_map: MapLike, method: str = "hvpr", conf: EvalConfig | None = None,
                 anchor: str = "end") -> None:
        self.models = dict(ref_map.models)
        conf = (conf or EvalConfig()).replace(window="causal", methods=(method,))
        if conf.seq_len is None and "seqnet" in self.models:
            conf = conf.replace(seq_len=self.models["seqnet"].seq_len)
        self.conf, self.method = conf.replace(seq_len=conf.length), parse_method(method)
        self.anchor = check_choice("anchor", anchor, ANCHORS)
        if self.method.matcher is not None and self.method.matcher not in WINDOW_MATCHERS:
            raise ConfigError(f"method {method!r}: matcher {self.method.matcher!r} has no online form; "
                              f"valid online matchers: {', '.join(WINDOW_MATCHERS)}")
        self.device = get_device(conf.device)
        for model in self.models.values():
            model.to(self.device).eval()
        self.radius, self.k = ref_map.radius, max(conf.ks)
        self._attach(ref_map)
        self.frame = 0
        self.reset()

    def _attach(self, ref_map: MapLike) -> None:
        """Check the map's reference traverse, find its items and describe them (once)."""
        t = ref_map.reference
        if max(self.conf.length, self.conf.match_len) > len(t):
            raise ConfigError(f"seq_len={max(self.conf.length, self.conf.match_len)} is longer than the map's "
                              f"reference traverse ({len(t)} frames); use a shorter --seq-len")
        check_inputs(Dataset(t, t, ref_map.radius, name=getattr(ref_map, "name", "map")), [self.method],
                     self.models, self.conf.length, self.conf.match_len, self.conf.allow_mismatch)
        self.side = Side.of(t, self.conf.length, self.conf.match_len, "causal")
        if len(self.side.items) == 0:
            raise ConfigError(f"no reference frame has a full causal window of "
                              f"{max(self.conf.length, self.conf.match_len)} frames inside its sequence; "
                              "use a shorter --seq-len")
        self.ref_items, self.r_pos = self.side.items, t.positions[self.side.items]
        m = self.method
        r_items = None if m.shortlist is None else self._describe(t, m.shortlist, items=True)
        r_frames = None if m.frames is None else self._describe(t, FRAME_FEATURES[m.frames], items=False)
        self._prepare(t.dim, r_items, r_frames, self.side.match_starts)

    @property
    def seq_len(self) -> int:
        """L: the window of the sequence descriptors."""
        return self.conf.length

    @property
    def match_len(self) -> int:
        """L_m: the window of the sequence matchers."""
        return self.conf.match_len

    def _prepare(self, dim: int, r_items: torch.Tensor | None, r_frames: torch.Tensor | None,
                 match_starts: np.ndarray) -> None:
        """Rings and reference arrays: ``r_items [R, D1]`` (shortlists; None when searched otherwise),
        ``r_frames [Nr, D2]`` (matchers) and the items' L_m-window starts ``[R]``."""
        m, dev = self.method, self.device
        self.raw = Ring(self.seq_len, dim, torch.float32, dev)
        self.need = 1
        if m.shortlist is not None:  # k-NN and HVPR shortlists: the reference items' descriptors
            d = SEQUENCE_DESCRIPTORS[m.shortlist]
            self.short_fn, self.short_len = d.window_fn(self.models), d.length(self.seq_len)
            if r_items is not None:
                self.r_items, self.r_items_sq = r_items, sq_norms(r_items)
            self.need = self.short_len
        if m.frames is not None:  # matchers: every reference frame's descriptor
            d = SEQUENCE_DESCRIPTORS[FRAME_FEATURES[m.frames]]
            self.frame_fn, self.frame_len = d.window_fn(self.models), d.length(self.seq_len)
            self.r_frames, self.r_frames_sq = r_frames, sq_norms(r_frames)
            self.feats = Ring(self.match_len, r_frames.shape[1], torch.float32, dev)
            self.rows = Ring(self.match_len, len(r_frames), torch.float32, dev) if m.kind == "match" else None
            self.r_starts = torch.as_tensor(match_starts, device=dev)
            self.need = max(self.need, self.match_len)

    def _describe(self, t: Traverse, name: str, items: bool) -> torch.Tensor:
        """Reference descriptors ``name``: ``[R, D']`` of the items, or ``[Nr, D']`` of every frame's
        causal window (clamped at sequence bounds), computed as :class:`seqnet.eval.features.Descriptors` does."""
        d = SEQUENCE_DESCRIPTORS[name]
        if items and not d.single_frame:
            idx = window_frames(self.side.starts, self.seq_len)
        else:
            idx = window_indices(len(t), d.length(self.seq_len), "causal", t.seq_bounds)
            idx = idx[self.side.items] if items else idx
        out = describe_windows(t.descriptors, idx, d.window_fn(self.models), device=self.device,
                               progress=f"map {name}")
        return out.to(self.device)

    def reset(self) -> None:
        """Forget the recent frames (call at a sequence bound, or after a kidnap)."""
        self.raw.reset()
        if self.method.frames is not None:
            self.feats.reset()
            if self.rows is not None:
                self.rows.reset()

    def _window(self, length: int) -> torch.Tensor:
        """``[1, length, D]``: the last ``length`` raw frames, the oldest repeated when fewer were seen."""
        w = self.raw.window()
        if len(w) < length:
            w = torch.cat([w[:1].expand(length - len(w), -1), w])
        return w[len(w) - length :][None]

    @torch.no_grad()
    def step(self, descriptor: ArrayLike) -> Estimate:
        """Localise the next query frame ``descriptor [D]``."""
        t0 = time.perf_counter()
        x = as_tensor(descriptor, self.device, "query frame").reshape(-1)
        if x.shape[0] != self.raw.buf.shape[1]:
            raise ConfigError(f"dimension mismatch: query frame D={x.shape[0]}, map D={self.raw.buf.shape[1]}")
        if not bool(torch.isfinite(x).all()):
            raise ConfigError(f"query frame {self.frame} holds NaN or inf")
        self.raw.push(x)
        if self.method.frames is not None:
            feat = self.frame_fn(self._window(self.frame_len))[0]
            self.feats.push(feat)
            if self.rows is not None:
                self.rows.push(distance_row(feat, self.r_frames, self.r_frames_sq))
        seen = self.raw.count
        ranking = self._rank() if seen >= self.need else None
        est = self._estimate(ranking, seen >= max(self.seq_len, self.match_len))
        est.latency_ms = (time.perf_counter() - t0) * 1e3
        self.frame += 1
        return est

    def _rank(self) -> tuple[torch.Tensor, torch.Tensor] | None:
        """``(scores [k], items [k])`` of the latest frame, best first."""
        m = self.method
        if m.kind == "match":
            row = WINDOW_MATCHERS[m.matcher].score(self.rows.window(), anchor=self.anchor)[self.r_starts]
            v, i = topk_smallest(row[None], self.k)
            return v[0], i[0]
        q = self.short_fn(self._window(self.short_len))[0]
        v, i = self._shortlist(q, max(self.k, self.conf.top_k) if m.kind == "hvpr" else self.k)
        if len(i) == 0:  # an approximate index found nothing
            return None
        return (v, i) if m.kind == "knn" else self._rerank(i)

    def _shortlist(self, q: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
        """``(distances [k], items [k])`` of the reference items nearest to ``q [D1]`` (exact)."""
        v, i = topk_smallest(distance_row(q, self.r_items, self.r_items_sq)[None], k)
        return v[0], i[0]

    def _rerank(self, shortlist: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """HVPR: the top K of the shortlist re-ranked by the matcher, then the rest (score ``inf``)."""
        head = min(self.conf.top_k, len(shortlist))
        cand = shortlist[:head]
        q_start = torch.zeros(1, dtype=torch.long, device=self.device)
        scores = WINDOW_MATCHERS[self.method.matcher].pairs(self.feats.window(), self.r_frames, self.match_len,
                                                            q_start, self.r_starts[cand][None], anchor=self.anchor)[0]
        order = torch.sort(scores, stable=True).indices
        tail = torch.full((len(shortlist) - head,), float("inf"), dtype=scores.dtype, device=scores.device)
        return torch.cat([scores[order], tail]), torch.cat([cand[order], shortlist[head:]])

    def _estimate(self, ranking: tuple[torch.Tensor, torch.Tensor] | None, full: bool) -> Estimate:
        if ranking is None:
            empty = np.zeros(0)
            return Estimate(self.frame, -1, -1, float("nan"), 0.0, 0.0, full, empty.astype(np.int64), empty)
        scores, ranked = ranking[0].cpu().numpy(), ranking[1].cpu().numpy()
        conf = float(ratio_confidence(scores[None], ranked[None], self.r_pos, self.radius)[0])
        best = int(ranked[0])
        return Estimate(self.frame, best, int(self.ref_items[best]), float(scores[0]), conf, 0.0, full, ranked,
                        scores)


def replay(loc: Localizer, traverse: Traverse) -> Iterator[Estimate]:
    """Step ``loc`` through every frame of ``traverse`` in order, resetting at each sequence start."""
    starts = None if traverse.seq_bounds is None else traverse.seq_bounds[:, 0]
    for i in range(len(traverse)):
        if starts is not None and starts[i] == i and i > 0:
            loc.reset()
        yield loc.step(traverse.descriptors[i])
