"""The settings of an evaluation (:class:`EvalConfig`, ``seqnet eval``'s options): a small validated dataclass,
light to import (``seqnet eval --help`` and the localiser read its defaults without the evaluation's modules)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import TYPE_CHECKING

from ..core.config import Config, check_bool, check_choice, check_float, check_int, check_ints
from ..core.devices import check_device
from ..core.errors import ConfigError
from ..data.resample import RESAMPLE_SIDES
from ..methods.grammar import FUSE_WEIGHT, Method, default_methods, parse_method
from ..metrics.calibration import RISK, check_target
from ..metrics.consistency import CONFIDENCES
from ..metrics.recall import RECALL_DENOMINATORS, check_radius
from ..search.knn import KNN_BACKENDS
from ..sequence.windows import WINDOW_MODES, Windows, WindowSettings

if TYPE_CHECKING:
    from ..sequence.model import SeqNet


@dataclasses.dataclass(frozen=True)
class EvalConfig(WindowSettings, Config):
    """Settings of :func:`evaluate` (see ``seqnet eval --help``).

    Attributes:
        methods: method names (:mod:`seqnet.methods.grammar`); None: every default method the models allow.
        seq_len: window length L of the sequence descriptors (None: the S_L model's, else 5).
        match_len: length L_m of the sequence matchers (None: L).
        window: ``"centred"`` (the paper's) or ``"causal"`` (online).
        radius: localisation radius (None: the dataset's); a retrieved reference is correct within it (≤).
        extra_radii: further radii to report.
        ks: the K of Recall@K; recall_denominator: ``positives`` (queries with a correct reference, the
            original code's) or ``all`` (every evaluated query): :data:`seqnet.metrics.recall.RECALL_DENOMINATORS`.
        top_k: HVPR shortlist size K.
        fuse_weight, fuse_top_k: λ of the fused score and shortlist size K of ``hvpr-fused``
            (defaults :data:`seqnet.methods.grammar.FUSE_WEIGHT`, :data:`seqnet.methods.grammar.FUSED_TOP_K`).
        method_top_k, method_fuse_weight: ``{HVPR method name: K}`` and ``{hvpr-fused method name: λ}``, one
            method's own settings (e.g. chosen on val for it, :mod:`seqnet.eval.select`), in place of ``top_k`` /
            ``fuse_top_k`` and ``fuse_weight`` for that method only (:meth:`shortlist_size`, :meth:`weight`).
        split: the split evaluated by :func:`main` (None: test when defined, else all).
        resample_every, resample_side: keep every N-th frame (recorded order) of the query, reference or both
            sides of the evaluated split (:func:`seqnet.data.resample.resample_dataset`; None: all frames).
        backend: k-NN backend (a key of :data:`seqnet.search.knn.KNN_BACKENDS`).
        device: torch device (auto: CUDA when present).
        allow_mismatch: go on (with a warning) when reference and query descriptors, or a model and
            the descriptors, were made differently; by default each is an error. (An S_L model at another
            L >= w than it was trained with needs no flag: one info line, ``model_seq_len`` in the results.)
        common_queries: evaluate every method on the sequence methods' query and reference items (the
            paper's tables: one query set); by default a single-frame method (``single``, ``s1``) queries and
            indexes every frame (:mod:`seqnet.eval.evaluation`).
        target_precision, calibrate_split, risk: with a target, :func:`main` also evaluates ``calibrate_split``
            and gives each method a confidence threshold calibrated there, whose precision is ≥ the target
            with probability ≥ 1 − ``risk`` (:mod:`seqnet.metrics.calibration`), applied to the evaluated split.
        confidence: what a top-1's confidence is (:data:`seqnet.metrics.consistency.CONFIDENCES`): ``ratio``,
            from the query's own scores (the localiser's); ``sequence``, also whether the L neighbouring queries'
            top-1s agree with it (:mod:`seqnet.metrics.consistency`; the L before only, with causal windows).
    """

    methods: tuple[str, ...] | None = None
    seq_len: int | None = None
    match_len: int | None = None
    window: str = "centred"
    radius: float | None = None
    extra_radii: tuple[float, ...] = ()
    ks: tuple[int, ...] = (1, 5, 10, 20, 100)
    recall_denominator: str = "positives"
    top_k: int = 20
    fuse_weight: float = FUSE_WEIGHT
    fuse_top_k: int | None = None
    method_top_k: Mapping[str, int] | None = None
    method_fuse_weight: Mapping[str, float] | None = None
    split: str | None = None
    resample_every: int | None = None
    resample_side: str = "query"
    backend: str = "torch"
    device: str = "auto"
    allow_mismatch: bool = False
    common_queries: bool = False
    target_precision: float | None = None
    calibrate_split: str = "val"
    risk: float = RISK
    confidence: str = "ratio"

    def __post_init__(self) -> None:
        self._set("allow_mismatch", check_bool("allow_mismatch", self.allow_mismatch))
        self._set("common_queries", check_bool("common_queries", self.common_queries))
        if self.methods is not None:
            if isinstance(self.methods, str) or not self.methods:
                raise ConfigError(f"methods must be a non-empty list of method names, got {self.methods!r}")
            self._set("methods", tuple(parse_method(m).name for m in self.methods))
        for key in ("seq_len", "match_len", "resample_every"):
            if getattr(self, key) is not None:
                self._set(key, check_int(key, getattr(self, key), 1))
        check_choice("resample side", self.resample_side, RESAMPLE_SIDES)
        check_choice("recall denominator", self.recall_denominator, RECALL_DENOMINATORS)
        check_choice("window mode", self.window, WINDOW_MODES)
        check_choice("confidence", self.confidence, CONFIDENCES)
        if self.radius is not None:
            self._set("radius", check_radius(self.radius))
        self._set("extra_radii", tuple(check_radius(r) for r in self.extra_radii))
        self._set("ks", tuple(dict.fromkeys(check_ints("ks", self.ks, 1))))  # --ks 1,1,5: R@1 once
        self._set("top_k", check_int("top_k", self.top_k, 1))
        self._set("fuse_weight", check_float("fuse_weight", self.fuse_weight, 0.0))
        if self.fuse_top_k is not None:
            self._set("fuse_top_k", check_int("fuse_top_k", self.fuse_top_k, 1))
        self._set("method_top_k", per_method("method_top_k", self.method_top_k, False))
        self._set("method_fuse_weight", per_method("method_fuse_weight", self.method_fuse_weight, True))
        check_choice("k-NN backend", self.backend, KNN_BACKENDS)
        check_device(self.device)  # validates the device name
        if self.target_precision is not None:
            self._set("target_precision", check_target(self.target_precision, self.risk)[0])
        self._set("risk", check_target(0.5, self.risk)[1])

    @property
    def query_every(self) -> int | None:
        """N of ``resample_every`` when it thins the queries (side ``query`` or ``both``), else None: the
        evaluated queries of a split ``a:b`` are ``a, a + N, ...`` (what the leakage counts count)."""
        return self.resample_every if self.resample_every and self.resample_side != "reference" else None

    def resolve(self, models: Mapping[str, SeqNet], radius: float) -> EvalConfig:
        """L (the S_L model's when unset), the radius (the dataset's when unset) and the methods (the defaults
        the models allow when unset), resolved once."""
        model_len = getattr(models.get("seqnet"), "seq_len", None)
        seq_len = Windows.resolve(self.seq_len, None, self.window, model_len).seq_len
        return self.merge(radius=radius if self.radius is None else self.radius, seq_len=seq_len,
                            methods=self.methods or default_methods(models, seq_len))

    def shortlist_size(self, m: Method) -> int:
        """The HVPR shortlist size K of method ``m``: its own (``method_top_k``), else ``fuse_top_k`` for
        ``hvpr-fused``, else ``top_k``."""
        return (self.method_top_k or {}).get(m.name) or m.shortlist_size(self.top_k, self.fuse_top_k)

    def hvpr_settings(self, names: tuple[str, ...] | list[str]) -> str:
        """``hvpr K 20; hvpr-fused K 200, λ 0.25``: each HVPR method's settings among ``names`` (``top_k``,
        ``fuse_top_k``, ``fuse_weight``) under this configuration."""
        said = []
        for m in (parse_method(n) for n in self.methods or ()):
            if m.kind == "hvpr":
                k = f"K {self.shortlist_size(m)}" if {"top_k", "fuse_top_k"} & set(names) else ""
                lam = f"λ {self.weight(m):g}" if m.fused and "fuse_weight" in names else ""
                said.append(f"{m.name} {', '.join(v for v in (k, lam) if v)}")
        return "; ".join(said) or f"K {self.top_k}"

    def weight(self, m: Method) -> float:
        """λ of method ``m``'s fused score: its own (``method_fuse_weight``), else ``fuse_weight``, for
        ``hvpr-fused``; 0 (the matcher alone) for any other method."""
        own = (self.method_fuse_weight or {}).get(m.name)
        return m.fuse_weight(self.fuse_weight if own is None else own)


def per_method(name: str, values: Mapping[str, float] | None, fused: bool) -> dict[str, float] | None:
    """``values`` (``{method name: K}``, or ``{hvpr-fused method name: λ}`` when ``fused``) checked, with each
    name canonical (:func:`seqnet.methods.grammar.parse_method`); None or empty: None."""
    if not values:
        return None
    if not isinstance(values, Mapping):
        raise ConfigError(f"{name} must map method names to values, got {values!r:.80}")
    out: dict[str, float] = {}
    for key, value in values.items():
        m = parse_method(key)
        if m.kind != "hvpr" or (fused and not m.fused):
            raise ConfigError(f"{name}: {key!r} is not an {'hvpr-fused' if fused else 'HVPR'} method")
        out[m.name] = check_float(f"{name}[{key!r}]", value, 0.0) if fused else check_int(f"{name}[{key!r}]", value, 1)
    return out
