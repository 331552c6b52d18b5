"""Online localisation: one answer per query frame from causal windows, with a latency and a confidence.

:class:`Localizer` answers ``.step(descriptor [D]) -> Estimate`` for a stream of query frames with
any method of :mod:`seqnet.methods.grammar` whose matcher has an online form, against any
:class:`~seqnet.methods.protocol.Reference` — a dataset's reference traverse
(:func:`traverse_reference`) or an index map (:class:`seqnet.maps.Map`, ``--window causal``).

**The batch pipeline on the newest causal window, by construction.** The raw frames since the
last :meth:`Localizer.reset` are held in a ring of the last L; each new frame's frame descriptor
(its own, S_1, or a sequence descriptor of its window) is computed by
:func:`seqnet.sequence.described.describe_frames` — the function the evaluation describes whole
traverses with — into a ring of the last L_m; the newest item's shortlist descriptor by
:func:`~seqnet.sequence.described.describe_items`. The query is then ranked by
:func:`seqnet.methods.rank.rank`, the function ``seqnet eval`` ranks with, as a one-item query: k-NN,
whole-map matching and HVPR (fused or not) are the same code online and offline. A frame whose L-
and L_m-windows since the last reset are full (``Estimate.full_window``) is exactly an item of
``seqnet eval --window causal``, with the same ranking. Earlier frames are answered as soon as the
method's own windows are full (from the first frame for single-frame k-NN), else not at all
(``ref_index = -1``).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator, Mapping
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import ConfigError
from ..core.lazy import lazy_module, no_grad
from ..core.tensors import ArrayLike, as_tensor
from ..data.traverse import Traverse
from ..matching.online import Ring
from ..matching.registry import SEQUENCE_MATCHERS
from ..methods.checks import check_methods, check_models, check_resident, check_windows_fit
from ..methods.grammar import FRAME_FEATURES, FUSE_WEIGHT, Method, parse_method
from ..methods.protocol import Reference
from ..methods.rank import rank
from ..metrics.precision_recall import ratio_confidence
from ..reference.traverse import TraverseReference
from ..search.blocks import topk_smallest
from ..sequence.described import describe_frames, describe_items
from ..sequence.descriptors import SEQUENCE_DESCRIPTORS
from ..sequence.windows import Windows

torch = lazy_module("torch")

if TYPE_CHECKING:
    from ..sequence.model import SeqNet


@dataclasses.dataclass
class Estimate:
    """The answer for one query frame.

    Attributes:
        frame: index of the query frame in the stream (counted across resets).
        ref_index: the best reference item (index into :attr:`Localizer.ref_items`), -1 = no answer.
        ref_frame: its frame in the map's reference traverse, -1 = no answer.
        score: its score (lower is better; nan without an answer).
        confidence: ratio confidence in [0, 1] (:func:`seqnet.metrics.precision_recall.ratio_confidence`).
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


def online_method(method: str) -> Method:
    """The parsed method; a matcher without an online form (:data:`SEQUENCE_MATCHERS` ``online``) is refused."""
    m = parse_method(method)
    if m.matcher is not None and not SEQUENCE_MATCHERS[m.matcher].online:
        online = [k for k, v in SEQUENCE_MATCHERS.items() if v.online]
        raise ConfigError(f"method {method!r}: matcher {m.matcher!r} has no online form; "
                          f"valid online matchers: {', '.join(online)}")
    return m


def traverse_reference(t: Traverse, models: Mapping[str, SeqNet], method: str, windows: Windows,
                       device: torch.device, allow_mismatch: bool = False, name: str = "map") -> TraverseReference:
    """A reference traverse as the localiser's map (causal ``windows``), its models and lengths checked."""
    m = online_method(method)
    if m.single_frame:  # windows of one frame: a model the method does not use (S_L) is not checked against them
        models = {role: model for role, model in models.items() if role in m.models()}
    check_methods([m], models, windows.seq_len)
    check_models(models, t.dim, t.provenance, f"the map {name!r}", windows.seq_len, allow_mismatch)
    check_windows_fit(windows.longest, len(t), "the map's reference traverse", windows.longest_option)
    for model in models.values():
        model.to(device).eval()
    return TraverseReference(t, windows, models, device, name=name)


class _Newest:
    """The newest causal window as a one-item query of :func:`seqnet.methods.rank.rank`."""

    def __init__(self, item: torch.Tensor | None, frames: torch.Tensor | None, match_len: int) -> None:
        self._item, self._frames = item, frames
        self.match_starts = np.array([0 if frames is None else len(frames) - match_len], dtype=np.int64)
        self.items_index = np.array([0 if frames is None else len(frames) - 1], dtype=np.int64)  # the newest frame

    def items(self, name: str) -> torch.Tensor:
        return self._item[None]

    def frames(self, name: str) -> torch.Tensor:
        return self._frames

    def cost_ms(self, keys: list[tuple[str, str]]) -> float:
        return 0.0


class Localizer:
    """Frame-by-frame localisation against a reference (see the module docstring).

    Args:
        reference: the map (causal windows: L, L_m and the anchor of the variable-speed matchers).
        method: a method name (:mod:`seqnet.methods.grammar`) with an online form (not ``grh``).
        radius: localisation radius (for the confidence).
        top_k: HVPR shortlist size K; k: references ranked per frame.
        fuse_weight: λ of ``hvpr-fused``; fuse_top_k: its shortlist size (None:
            :data:`~seqnet.methods.grammar.FUSED_TOP_K`).
        exact: shortlist by exact search instead of the reference's ANN index.
        models: the models of the query side (default: the reference's).
        precision: None, or the half dtype the reference's exact searches read and multiply in.
    """

    def __init__(self, reference: Reference, method: str = "hvpr", radius: float = 1.0, top_k: int = 20, k: int = 20,
                 fuse_weight: float = FUSE_WEIGHT, fuse_top_k: int | None = None, exact: bool = False,
                 models: Mapping[str, SeqNet] | None = None, precision: torch.dtype | None = None) -> None:
        if reference.windows.mode != "causal":
            raise ConfigError(f"the map {reference.name} uses {reference.windows.mode} windows; the online "
                              "localiser needs causal ones (seqnet index build --window causal)")
        self.ref, self.method, self.windows = reference, online_method(method), reference.windows
        reference.check_method(self.method)
        self.models = dict(reference.models if models is None else models)
        reference.serve_online()  # searched every frame: kept in memory (the map's bytes), never streamed
        check_resident(reference, self.method, self.models)
        self.device, self.radius, self.k = reference.device, float(radius), int(k)
        self.top_k, self.fuse = self.method.shortlist_size(top_k, fuse_top_k), self.method.fuse_weight(fuse_weight)
        self.exact = bool(exact)
        self.as_given = reference.frame_indices  # frames are matrix rows: nothing to describe
        self.ref_items, self.r_pos = reference.items, reference.positions[reference.items]
        reference.prepare(self.method)  # describe the map once, before the first frame
        if precision is not None:
            reference.serve_online(precision)  # after the map is described in float32
        m, w = self.method, self.windows
        self.short_len = SEQUENCE_DESCRIPTORS[m.shortlist].length(w.seq_len) if m.shortlist else 1
        self.frames_name = FRAME_FEATURES[m.frames] if m.frames else None
        self.need = max(self.short_len, w.match_len if m.frames else 1)
        self.raw = Ring(w.seq_len, reference.input_dim, torch.float32, self.device)
        self.feats: Ring | None = None
        self.rows: Ring | None = None
        self._starts = torch.as_tensor(reference.match_starts, device=self.device)
        self.frame = 0
        self.reset()

    @property
    def seq_len(self) -> int:
        """L: the window of the sequence descriptors."""
        return self.windows.seq_len

    @property
    def match_len(self) -> int:
        """L_m: the window of the sequence matchers."""
        return self.windows.match_len

    def reset(self) -> None:
        """Forget the recent frames (call at a sequence bound, or after a kidnap)."""
        self.raw.reset()
        for ring in (self.feats, self.rows):
            if ring is not None:
                ring.reset()

    @no_grad
    def step(self, descriptor: ArrayLike) -> Estimate:
        """Localise the next query frame ``descriptor [D]``."""
        t0 = time.perf_counter()
        x = as_tensor(descriptor, self.device, "query frame").reshape(-1)
        if x.shape[0] != self.raw.buf.shape[1]:
            raise ConfigError(f"dimension mismatch: query frame D={x.shape[0]}, map D={self.raw.buf.shape[1]}")
        if not bool(torch.isfinite(x).all()):
            raise ConfigError(f"query frame {self.frame} holds NaN or inf")
        self.raw.push(x)
        recent = self.raw.window()  # the raw frames since the reset (the last L), oldest first
        if self.frames_name is not None:
            self._push_frame(self._newest_frame(recent, self.frames_name))
        seen = self.raw.count
        ranking = self._rank(recent) if seen >= self.need else None
        est = self._estimate(ranking, seen >= self.windows.longest)
        est.latency_ms = (time.perf_counter() - t0) * 1e3
        self.frame += 1
        return est

    def _newest_frame(self, recent: torch.Tensor, name: str) -> torch.Tensor:
        """The newest frame's ``name`` descriptor ``[D2]`` (as given when the frames are matrix rows)."""
        if self.as_given:
            return recent[-1]
        return describe_frames(recent, None, name, self.windows, self.models, self.device,
                               which=np.array([len(recent) - 1]))[0].to(self.device)

    def _push_frame(self, feat: torch.Tensor) -> None:
        """The newest frame descriptor ``[D2]`` into the ring of the last L_m; for a whole-map matcher its
        distance row to the map into the ring of the last L_m rows (the matcher's online form reads them)."""
        if self.feats is None:
            self.feats = Ring(self.match_len, feat.shape[0], torch.float32, self.device)
        self.feats.push(feat)
        if self.method.kind == "match":
            row = self.ref.frame_distances(self.frames_name, feat)
            if self.rows is None:
                self.rows = Ring(self.match_len, row.shape[0], row.dtype, self.device)
            self.rows.push(row)

    def _match(self) -> tuple[np.ndarray, np.ndarray]:
        """A whole-map matcher on the newest window: its online form (:data:`SEQUENCE_MATCHERS` ``window``)
        on the last L_m distance rows, at the reference items, the k best."""
        spec = SEQUENCE_MATCHERS[self.method.matcher]
        row = spec.window(self.rows.window(), **spec.options(self.windows.anchor))[self._starts]
        v, i = topk_smallest(row[None], self.k)
        return v[0].cpu().numpy(), i[0].cpu().numpy()

    def _rank(self, recent: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
        """``(scores [k'], items [k'])`` of the newest frame, best first (:func:`seqnet.methods.rank.rank`)."""
        m, item = self.method, None
        if m.kind == "match":
            return self._match()
        if m.shortlist is not None:
            if SEQUENCE_DESCRIPTORS[m.shortlist].single_frame:
                item = self._newest_frame(recent, m.shortlist)
            else:
                item = describe_items(recent, np.array([len(recent) - self.seq_len]), m.shortlist, self.windows,
                                      self.models, self.device)[0]
        frames = self.feats.window() if self.feats is not None else None
        scores, items, _ = rank(m, _Newest(item, frames, self.match_len), self.ref, self.k, self.top_k, self.fuse,
                               self.exact)
        return scores[0], items[0]

    def _estimate(self, ranking: tuple[np.ndarray, np.ndarray] | None, full: bool) -> Estimate:
        if ranking is not None:
            scores, ranked = np.asarray(ranking[0]), np.asarray(ranking[1]).astype(np.int64, copy=False)
            if (ranked < 0).any():  # an approximate index may find fewer than asked
                scores, ranked = scores[ranked >= 0], ranked[ranked >= 0]
        if ranking is None or len(ranked) == 0:
            empty = np.zeros(0)
            return Estimate(self.frame, -1, -1, float("nan"), 0.0, 0.0, full, empty.astype(np.int64), empty)
        conf = float(ratio_confidence(scores[None], ranked[None], self.r_pos, self.radius)[0])
        best = int(ranked[0])
        return Estimate(self.frame, best, int(self.ref_items[best]), float(scores[0]), conf, 0.0, full, ranked,
                        scores)


def replay(loc: Localizer, traverse: Traverse, frames: ArrayLike | None = None) -> Iterator[Estimate]:
    """Step ``loc`` through every frame of ``traverse`` in order (its descriptors, or ``frames [N, D]`` in
    their place: a matrix's row numbers), resetting at each sequence start."""
    starts = None if traverse.seq_bounds is None else traverse.seq_bounds[:, 0]
    frames = traverse.descriptors if frames is None else frames
    for i in range(len(traverse)):
        if starts is not None and starts[i] == i and i > 0:
            loc.reset()
        yield loc.step(frames[i])
