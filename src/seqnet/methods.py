"""Place-recognition methods as data: what each method name means.

* single-frame / sequence-descriptor retrieval (k-NN): ``single``, ``s1``, ``smoothing``, ``delta``,
  ``seqnet`` (S_L);
* SeqMatch over single descriptors: ``raw+seqmatch``, ``s1+seqmatch``, ``delta+seqmatch``;
* HVPR: ``hvpr`` (default shortlister and re-ranker) or ``hvpr-<shortlister>`` (e.g. ``hvpr-delta``).
"""

from __future__ import annotations

import dataclasses

from .errors import ConfigError

SHORTLISTERS = ("single", "s1", "smoothing", "delta", "seqnet")
SEQMATCH_INPUTS = ("raw", "s1", "delta")
NEEDS_MODEL = {"s1": "s1", "seqnet": "seqnet"}


@dataclasses.dataclass(frozen=True)
class Method:
    """A parsed method: ``kind`` is "knn", "seqmatch" or "hvpr"."""

    name: str
    kind: str
    shortlist: str | None = None  # knn / hvpr: descriptor used for k-NN
    rerank: str | None = None  # seqmatch / hvpr: single descriptor for SeqMatch

    def models(self) -> set[str]:
        """Model roles (``"seqnet"``, ``"s1"``) this method needs."""
        used = {self.shortlist, self.rerank}
        return {NEEDS_MODEL[u] for u in used if u in NEEDS_MODEL}


def valid_methods() -> list[str]:
    """All method names accepted by :func:`parse_method`."""
    return [
        *SHORTLISTERS,
        *(f"{s}+seqmatch" for s in SEQMATCH_INPUTS),
        "hvpr",
        *(f"hvpr-{s}" for s in SHORTLISTERS),
    ]


def parse_method(name: str, have_models: set[str], shortlist: str | None = None, rerank: str | None = None) -> Method:
    """Parse a method name; ``hvpr`` defaults depend on the trained models available.

    Args:
        name: method name (see :func:`valid_methods`).
        have_models: the model roles available (subset of ``{"seqnet", "s1"}``).
        shortlist: default HVPR shortlister (None: ``seqnet`` if available else ``delta``).
        rerank: HVPR re-ranking descriptor (None: ``s1`` if available else ``raw``).
    """
    if name in SHORTLISTERS:
        m = Method(name, "knn", shortlist=name)
    elif name.endswith("+seqmatch") and name[: -len("+seqmatch")] in SEQMATCH_INPUTS:
        m = Method(name, "seqmatch", rerank=name[: -len("+seqmatch")])
    elif name == "hvpr" or (name.startswith("hvpr-") and name[5:] in SHORTLISTERS):
        sl = name[5:] if name != "hvpr" else shortlist or ("seqnet" if "seqnet" in have_models else "delta")
        rr = rerank or ("s1" if "s1" in have_models else "raw")
        if sl not in SHORTLISTERS:
            raise ConfigError(f"unknown HVPR shortlister {sl!r}; valid: {', '.join(SHORTLISTERS)}")
        if rr not in SEQMATCH_INPUTS:
            raise ConfigError(f"unknown HVPR re-ranker {rr!r}; valid: {', '.join(SEQMATCH_INPUTS)}")
        m = Method(name, "hvpr", shortlist=sl, rerank=rr)
    else:
        raise ConfigError(f"unknown method {name!r}; valid: {', '.join(valid_methods())}")
    missing = m.models() - have_models
    if missing:
        hints = {"seqnet": "an S_L model (--model or --shortlist-model CKPT)",
                 "s1": "an S_1 model (--model or --rerank-model CKPT)"}
        raise ConfigError(f"method {name!r} needs " + " and ".join(hints[x] for x in sorted(missing)))
    return m
