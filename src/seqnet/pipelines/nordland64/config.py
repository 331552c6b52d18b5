"""Settings of the Nordland64 benchmark, as data (tuned on the val range only; see docs/benchmark_nordland64.md)."""

from __future__ import annotations

import dataclasses

from ...core.config import Config, check_bool, check_choice, check_float, check_int, check_ints, check_range
from ...core.errors import ConfigError
from ...describe import DescribeConfig
from ...describe.config import check_size
from ...eval.config import EvalConfig, per_method
from ...methods.grammar import FUSE_WEIGHT, FUSED_TOP_K, parse_method
from ...metrics.recall import RECALL_DENOMINATORS
from ...train import TrainConfig
from .speed import check_speed

# what the benchmark chooses on val when not given (docs/benchmark_nordland64.md, "Chosen on val")
SELECTABLE = ("descriptor", "top_k", "fuse_top_k", "fuse_weight")
# the descriptors the val proxy chooses among: pixels (DESCRIBE) and the CNN methods at cnn_size whose
# backbone weights ship with an installed package (nothing is downloaded); netvlad+equalize: NetVLAD of the raw and
# the histogram-equalised frames, concatenated (seqnet.describe.views)
DESCRIPTOR_CANDIDATES = ("pixels", "netvlad", "netvlad+equalize", "gem", "gmp")

# 16x16 patches: learned S_L / S_1 clearly better on val than SeqSLAM's 8x8 (raw single worse)
DESCRIBE = DescribeConfig(method="pixels", patch=16, size="native")
# S_L: w = L = 5 (one temporal kernel over the whole window) beat the paper's w = 3 on val
TRAIN = TrainConfig(seq_len=5, w=5, epochs=10, optimizer="adam", lr=1e-4, weight_decay=0.0, margin=0.3,
                    batch_size=16, n_negatives=10, n_neg_sample=1000, seed=0)
METHODS = ("single", "s1", "smoothing", "delta", "seqnet", "raw+seqmatch", "s1+seqmatch", "delta+seqmatch", "hvpr",
           "hvpr-single", "hvpr-delta", "hvpr-fused")
# evaluated as well when the query is re-sampled at variable speed (query_speed)
VARIABLE_SPEED_METHODS = ("raw+vseqmatch", "s1+vseqmatch", "s1+graph", "hvpr-seqnet:s1+vseqmatch",
                          "hvpr-seqnet:s1+graph", "hvpr-fused:s1+vseqmatch", "hvpr-fused:s1+graph")


@dataclasses.dataclass(frozen=True)
class Nordland64Config(Config):
    """Every setting of ``seqnet benchmark nordland64``.

    Attributes:
        names_file: the clean frame list (frames in tunnels / stops removed).
        train_range, val_range, test_range: half-open place ranges (places = clean frames in both seasons).
        radius: localisation radius in frame steps (position = frame number / 10); pos_radius /
            neg_radius: training positives / negatives.
        describe: the single-image descriptor (fitted state, if any, fitted on the train range).
        pca_dims: PCA of the train descriptors before training, folded into the models (0: none);
            pca_whiten: whiten it.
        symmetric: train winter → summer and summer → winter; flip: add the mirrored train images.
        seq_len: L of the evaluation windows (S_L and SeqMatch), any L >= ``train.w``.
        train / train_s1: training of S_L (at ``train.seq_len``) and S_1 (epoch chosen on val).
        methods, top_k, ks: what is evaluated (with ``query_speed`` also
            :data:`VARIABLE_SPEED_METHODS`); device: torch device.
        fuse_weight, fuse_top_k: λ and shortlist size of ``hvpr-fused`` (chosen on val, see
            docs/experiments.md).
        method_top_k, method_fuse_weight: one HVPR method's own K / λ (each chosen on val for that method,
            :func:`seqnet.eval.select.select_hvpr`), in place of the above for it (as in :class:`EvalConfig`).
        query_speed: ``(A, B)``: evaluate on the winter traverse of the val and test ranges re-sampled
            at A to B times the reference speed (:mod:`.speed`; training unchanged); None: as filmed.
        speed_seed: seed of the speed profile (the val and test ranges get their own streams).
        recall_denominator: ``positives`` (queries with a correct reference) or ``all`` queries.
        select: what is chosen on the val range before use (:data:`SELECTABLE`): ``descriptor`` (among
            ``descriptors``, by a model-free proxy before training, :mod:`.select`), ``top_k``, ``fuse_top_k``,
            ``fuse_weight`` (by val R@1 after training, :mod:`seqnet.eval.select`); the others are used as given.
        descriptors: the candidates of the descriptor choice (``pixels``: ``describe`` when it is pixels, else
            :data:`DESCRIBE`); cnn_size: the (W, H) the CNN candidates read the frames at.
    """

    names_file: str = "nordland_clean_imageNames.txt"
    train_range: tuple[int, int] = (0, 1650)
    val_range: tuple[int, int] = (1660, 1930)
    test_range: tuple[int, int] = (1940, 2761)
    radius: float = 1.0
    pos_radius: float = 1.0
    neg_radius: float = 4.0
    describe: DescribeConfig = DESCRIBE
    pca_dims: int = 256
    pca_whiten: bool = False
    symmetric: bool = True
    flip: bool = True
    seq_len: int = 5
    train: TrainConfig = TRAIN
    train_s1: TrainConfig = TRAIN.merge(seq_len=1, w=1, lr=3e-4)
    methods: tuple[str, ...] = METHODS
    top_k: int = 20
    fuse_weight: float = FUSE_WEIGHT  # the library's λ and K (chosen on this benchmark's val, both speeds)
    fuse_top_k: int = FUSED_TOP_K
    method_top_k: dict[str, int] | None = None
    method_fuse_weight: dict[str, float] | None = None
    ks: tuple[int, ...] = (1, 5, 10, 20)
    device: str = "auto"
    query_speed: tuple[float, float] | None = None
    speed_seed: int = 0
    recall_denominator: str = "positives"
    select: tuple[str, ...] = SELECTABLE
    descriptors: tuple[str, ...] = DESCRIPTOR_CANDIDATES
    cnn_size: tuple[int, int] = (128, 64)

    def __post_init__(self) -> None:
        for key in ("train_range", "val_range", "test_range"):
            self._set(key, check_range(key, getattr(self, key)))
        for key in ("radius", "pos_radius", "neg_radius"):
            self._set(key, check_float(key, getattr(self, key), 0.0, strict=True))
        if self.pos_radius > self.neg_radius:
            raise ConfigError(f"need pos_radius <= neg_radius, got {self.pos_radius} and {self.neg_radius}")
        self._set("pca_dims", check_int("pca_dims", self.pca_dims, 0))
        for key in ("pca_whiten", "symmetric", "flip"):
            self._set(key, check_bool(key, getattr(self, key)))
        self._set("seq_len", check_int("seq_len", self.seq_len, 1))
        if self.seq_len < self.train.w:  # S_L is valid at any L >= w (the paper trains Nordland at 10, tests at 5)
            raise ConfigError(f"the S_L model (w={self.train.w}) is evaluated with L={self.seq_len}, shorter than "
                              f"its convolution width; give seq_len >= {self.train.w}")
        self._set("methods", tuple(parse_method(m).name for m in self.methods))
        self._set("top_k", check_int("top_k", self.top_k, 1))
        self._set("fuse_weight", check_float("fuse_weight", self.fuse_weight, 0.0))
        self._set("fuse_top_k", check_int("fuse_top_k", self.fuse_top_k, 1))
        self._set("method_top_k", per_method("method_top_k", self.method_top_k, False))
        self._set("method_fuse_weight", per_method("method_fuse_weight", self.method_fuse_weight, True))
        self._set("ks", check_ints("ks", self.ks, 1))
        if self.query_speed is not None:
            self._set("query_speed", check_speed(self.query_speed))
        self._set("speed_seed", check_int("speed_seed", self.speed_seed, 0))
        self._set("recall_denominator", check_choice("recall_denominator", self.recall_denominator,
                                                     RECALL_DENOMINATORS))
        self._set("select", tuple(dict.fromkeys(check_choice("select", x, SELECTABLE) for x in self.select)))
        self._set("descriptors", tuple(dict.fromkeys(check_choice("descriptor", x, DESCRIPTOR_CANDIDATES)
                                                     for x in self.descriptors)))
        if not self.descriptors:
            raise ConfigError("descriptors: give at least one candidate (e.g. pixels)")
        size = check_size(self.cnn_size if isinstance(self.cnn_size, str) else tuple(self.cnn_size))
        if isinstance(size, str):
            raise ConfigError(f"cnn_size must be W x H (e.g. 128x64), got {self.cnn_size!r}")
        self._set("cnn_size", size)

    @property
    def eval_methods(self) -> tuple[str, ...]:
        """The methods evaluated: ``methods``, and with ``query_speed`` the velocity-robust ones."""
        extra = VARIABLE_SPEED_METHODS if self.query_speed is not None else ()
        return (*self.methods, *(m for m in extra if m not in self.methods))

    def eval_config(self) -> EvalConfig:
        """The evaluation settings of the val and test ranges."""
        return EvalConfig(methods=self.eval_methods, seq_len=self.seq_len, ks=self.ks, top_k=self.top_k,
                          fuse_weight=self.fuse_weight, fuse_top_k=self.fuse_top_k, method_top_k=self.method_top_k,
                          method_fuse_weight=self.method_fuse_weight, device=self.device,
                          recall_denominator=self.recall_denominator,
                          common_queries=True)  # the paper's Table I: every method on one query set
