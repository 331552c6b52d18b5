"""Place-recognition methods, named from the tables of descriptors and matchers.

A method name is one of:

* ``<descriptor>`` — k-NN retrieval with a key of :data:`SEQUENCE_DESCRIPTORS` (``single``, ``s1``,
  ``smoothing``, ``delta``, ``delta-paper``, ``seqnet``; ``delta-orig``, the earlier name of
  ``delta-paper``, is read as it wherever it appears in a name, and the parsed name says ``delta-paper``);
* ``<frames>+<matcher>`` — a sequence matcher (:data:`SEQUENCE_MATCHERS`: ``seqmatch``,
  ``seqmatch-rev``, ...) over the whole map on frame descriptors (:data:`FRAME_FEATURES`: ``raw``,
  ``s1``, ``delta``, ...), e.g. ``raw+seqmatch``, ``s1+seqmatch``;
* ``hvpr-<descriptor>[:<frames>+<matcher>]`` — HVPR: shortlist the top K by k-NN on the descriptor,
  re-rank them with the matcher (default ``s1+seqmatch``, the paper's re-ranker);
* ``hvpr`` — the paper's HVPR: ``hvpr-seqnet:s1+seqmatch`` (S_L shortlist, SeqMatch on S_1);
* ``hvpr-fused[:<frames>+<matcher>]`` — HVPR whose re-ranking score fuses the matcher with the S_L
  shortlist distance (``matcher / L_m + λ · d_S_L``, :func:`seqnet.matching.hvpr.hvpr`; λ and the shortlist
  size are :class:`seqnet.eval.evaluate.EvalConfig` settings), re-ranker default ``s1+seqmatch``.

A name means the same thing whatever models are given: a method whose model is missing is an
error naming the model, never a silent substitute.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Collection
from typing import Any

from ..core.errors import ConfigError
from ..matching.registry import SEQUENCE_MATCHERS
from ..sequence.descriptors import SEQUENCE_DESCRIPTORS, descriptor_name

# frame descriptors a matcher can run on: "raw" is each frame's own descriptor; every other sequence
# descriptor is computed over each frame's window (clamped at sequence bounds)
# hvpr-fused's score matcher/L_m + λ·d(S_L) over the S_L top K, whatever --top-k says: λ = 0.25, K = 200 were the
# best mean val R@1 of 3 seeds over the filmed speed and 0.5-2x on Nordland64 (docs/benchmark_nordland64.md)
FUSE_WEIGHT, FUSED_TOP_K = 0.25, 200
FRAME_FEATURES: dict[str, str] = {"raw": "single", **{k: k for k in SEQUENCE_DESCRIPTORS if k != "single"}}
HVPR_RERANK = "s1+seqmatch"  # the paper's re-ranker
HVPR_ALIAS = "hvpr"
HVPR_FUSED = "hvpr-fused"  # S_L shortlist, fused re-ranking score
METHOD_KINDS = ("knn", "match", "hvpr")


@dataclasses.dataclass(frozen=True)
class Method:
    """A parsed method name (see the module docstring)."""

    name: str
    kind: str  # one of METHOD_KINDS
    shortlist: str | None = None  # knn / hvpr: key of SEQUENCE_DESCRIPTORS
    frames: str | None = None  # match / hvpr: key of FRAME_FEATURES
    matcher: str | None = None  # match / hvpr: key of SEQUENCE_MATCHERS
    fused: bool = False  # hvpr: re-rank by the matcher score fused with the shortlist distance

    @property
    def rerank(self) -> str | None:
        """``<frames>+<matcher>``, or None for k-NN methods."""
        return f"{self.frames}+{self.matcher}" if self.frames else None

    @property
    def single_frame(self) -> bool:
        """Whether the method compares one frame with one frame (k-NN on a single-frame descriptor: ``single``,
        ``s1``): it needs no window, so it queries and indexes every frame whatever L is."""
        return self.kind == "knn" and SEQUENCE_DESCRIPTORS[self.shortlist].single_frame

    @property
    def rate_sensitive(self) -> bool:
        """Whether the method assumes query and reference advance by equal steps per frame: a multi-frame
        descriptor (S_L, smoothing, delta: as shortlist or as the matched frames) or a matcher that is not
        speed-robust (``seqmatch``)."""
        if self.single_frame:
            return False
        multi = any(not SEQUENCE_DESCRIPTORS[d].single_frame for d in self.descriptors())
        return multi or not SEQUENCE_MATCHERS[self.matcher].speed_robust

    def descriptors(self) -> list[str]:
        """The sequence descriptors this method computes (shortlist, then frame descriptor)."""
        return [d for d in (self.shortlist, self.frames and FRAME_FEATURES[self.frames]) if d]

    def models(self) -> set[str]:
        """Model roles (``"seqnet"`` = S_L, ``"s1"`` = S_1) this method needs."""
        return {m for d in self.descriptors() if (m := SEQUENCE_DESCRIPTORS[d].model)}

    def min_len(self) -> int:
        """The shortest sequence length L its descriptors accept."""
        return max(SEQUENCE_DESCRIPTORS[d].min_len for d in self.descriptors())

    def shortlist_size(self, top_k: int, fuse_top_k: int | None) -> int:
        """The HVPR shortlist size K: ``fuse_top_k`` (default :data:`FUSED_TOP_K`) for ``hvpr-fused``, else
        ``top_k``."""
        return (fuse_top_k or FUSED_TOP_K) if self.fused else top_k

    def fuse_weight(self, weight: float) -> float:
        """λ of the fused score: ``weight`` for ``hvpr-fused``, 0 (the matcher alone) otherwise."""
        return weight if self.fused else 0.0

    def summary(self) -> dict[str, Any]:
        """What the method is (stored in results): kind, shortlister, re-ranker (and ``fused`` when it is)."""
        return {"kind": self.kind, "shortlist": self.shortlist, "rerank": self.rerank,
                **({"fused": True} if self.fused else {})}


def _parse_rerank(text: str, name: str) -> tuple[str, str]:
    frames, sep, matcher = text.rpartition("+")
    if not sep or frames not in FRAME_FEATURES or matcher not in SEQUENCE_MATCHERS:
        raise ConfigError(f"method {name!r}: re-ranker {text!r} is not <frames>+<matcher> with frames one of "
                          f"{', '.join(FRAME_FEATURES)} and matcher one of {', '.join(SEQUENCE_MATCHERS)}")
    return frames, matcher


def parse_method(name: str) -> Method:
    """Parse a method name (see the module docstring); :class:`ConfigError` names the valid forms."""
    if not isinstance(name, str) or not name:
        raise ConfigError(f"a method name must be a non-empty string, got {name!r}; "
                          f"valid: {', '.join(valid_methods())}")
    name = canonical_name(name)
    if name in SEQUENCE_DESCRIPTORS:
        return Method(name, "knn", shortlist=name)
    if name == HVPR_ALIAS:
        return Method(name, "hvpr", "seqnet", *_parse_rerank(HVPR_RERANK, name))
    if name == HVPR_FUSED or name.startswith(HVPR_FUSED + ":"):
        rerank = name[len(HVPR_FUSED) + 1 :]
        return Method(name, "hvpr", "seqnet", *_parse_rerank(rerank or HVPR_RERANK, name), fused=True)
    if name.startswith("hvpr-"):
        shortlist, _, rerank = name[5:].partition(":")
        if shortlist not in SEQUENCE_DESCRIPTORS:
            raise ConfigError(f"method {name!r}: unknown HVPR shortlister {shortlist!r}; "
                              f"valid: {', '.join(SEQUENCE_DESCRIPTORS)}")
        return Method(name, "hvpr", shortlist, *_parse_rerank(rerank or HVPR_RERANK, name))
    if "+" in name:
        frames, matcher = name.rsplit("+", 1)
        if frames in FRAME_FEATURES and matcher in SEQUENCE_MATCHERS:
            return Method(name, "match", frames=frames, matcher=matcher)
    raise ConfigError(f"unknown method {name!r}; valid: {', '.join(valid_methods())}, or "
                      "hvpr-<shortlister>:<frames>+<matcher>")


def canonical_name(name: str) -> str:
    """``name`` with every descriptor alias (:data:`seqnet.sequence.descriptors.DESCRIPTOR_ALIASES`) replaced by
    its descriptor: ``hvpr-delta-orig:delta-orig+seqmatch`` → ``hvpr-delta-paper:delta-paper+seqmatch``."""
    def part(text: str) -> str:  # <descriptor>, <frames>+<matcher> or hvpr-<descriptor>
        prefix = "hvpr-" if text.startswith("hvpr-") else ""
        frames, plus, matcher = text[len(prefix):].rpartition("+")
        return prefix + (descriptor_name(frames) + plus + matcher if plus else descriptor_name(matcher))

    head, sep, tail = name.partition(":")
    return part(head) + sep + (part(tail) if sep else "")


def valid_methods() -> list[str]:
    """The method names without the optional ``:<frames>+<matcher>`` re-ranker suffix."""
    return [*SEQUENCE_DESCRIPTORS, *(f"{f}+{m}" for m in SEQUENCE_MATCHERS for f in FRAME_FEATURES), HVPR_ALIAS,
            HVPR_FUSED, *(f"hvpr-{d}" for d in SEQUENCE_DESCRIPTORS)]


# The methods run when none are named, in pipeline order; those whose models or L are missing are left out.
DEFAULT_METHODS = ("single", "s1", "smoothing", "delta", "seqnet", "raw+seqmatch", "s1+seqmatch", "delta+seqmatch",
                   "hvpr", "hvpr-delta:raw+seqmatch")


def default_methods(models: Collection[str], seq_len: int) -> list[str]:
    """:data:`DEFAULT_METHODS` that the available model roles and the sequence length L allow.

    ``hvpr-delta:raw+seqmatch`` (the model-free HVPR) is only a default when the paper's ``hvpr``
    cannot run.
    """
    parsed = [parse_method(n) for n in DEFAULT_METHODS]
    ok = [m.name for m in parsed if m.models() <= set(models) and m.min_len() <= seq_len]
    return [n for n in ok if not (n == "hvpr-delta:raw+seqmatch" and HVPR_ALIAS in ok)]


def needs(m: Method) -> list[tuple[str, str]]:
    """The descriptors ``m`` reads of each side: ``("items", shortlist)`` and / or ``("frames", frames)``."""
    return ([("items", m.shortlist)] if m.shortlist else []) + ([("frames", FRAME_FEATURES[m.frames])] if m.frames
                                                                 else [])
