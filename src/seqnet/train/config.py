"""Training settings: :class:`TrainConfig` (the paper's defaults) and the :class:`MiningConfig` it hands
to triplet mining, both small frozen dataclasses that validate themselves (:mod:`seqnet.core.config`).

Dataset-dependent defaults (``out_dims`` = the input dimension, the radii from ``dataset.extra``
else the localisation radius and 4×) are filled by :meth:`TrainConfig.resolve`; the resolved
configuration is what a run stores and what resuming compares against.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from ..core.config import Config, check_choice, check_float, check_int
from ..core.devices import check_device
from ..core.errors import ConfigError
from ..core.lazy import lazy_module
from ..data.traverse import Dataset
from ..security.inputs import ErrorType
from ..security.limits import DIM_MAX, INDEX_MAX, SEQ_MAX, number
from ..sequence.windows import WINDOW_MODES, check_speed_range
from .losses import LOSSES

torch = lazy_module("torch")

Params = Iterable["torch.nn.Parameter"]


def _sgd(params: Params, conf: TrainConfig) -> torch.optim.Optimizer:
    return torch.optim.SGD(params, lr=conf.lr, momentum=conf.momentum, weight_decay=conf.weight_decay)


def _adam(params: Params, conf: TrainConfig) -> torch.optim.Optimizer:
    return torch.optim.Adam(params, lr=conf.lr, weight_decay=conf.weight_decay)


OPTIMIZERS: dict[str, Callable[[Params, TrainConfig], torch.optim.Optimizer]] = {"sgd": _sgd, "adam": _adam}
RESUME_OVERRIDABLE = ("epochs", "patience", "device")


def check_radii(pos_radius: float, neg_radius: float) -> tuple[float, float]:
    """Validate the positive and negative radii (``0 < pos_radius <= neg_radius``)."""
    p = check_float("pos_radius", pos_radius, 0.0, strict=True)
    n = check_float("neg_radius", neg_radius, 0.0, strict=True)
    if n < p:
        raise ConfigError(f"need pos_radius <= neg_radius, got pos_radius={p:g}, neg_radius={n:g} "
                          "(hint: --pos-radius / --neg-radius, in the dataset's position unit)")
    return p, n


@dataclasses.dataclass(frozen=True)
class MiningConfig(Config):
    """Settings of triplet mining (see :mod:`seqnet.train.mining`).

    Attributes:
        pos_radius: positives lie within this distance (position unit of the dataset).
        neg_radius: negatives lie beyond it (>= pos_radius).
        n_negatives: hard negatives kept per query K.
        n_neg_sample: negatives sampled per query to choose them from.
        margin: triplet margin (a negative makes a triplet only if ``d_neg < d_pos + margin``).
        cache_refresh: queries between refreshes of the mining descriptors (0: once per epoch).
    """

    pos_radius: float
    neg_radius: float
    n_negatives: int = 10
    n_neg_sample: int = 1000
    margin: float = 0.3
    cache_refresh: int = 1000

    def __post_init__(self) -> None:
        p, n = check_radii(self.pos_radius, self.neg_radius)
        self._set("pos_radius", p)
        self._set("neg_radius", n)
        self._set("n_negatives", check_int("n_negatives", self.n_negatives, 1))
        self._set("n_neg_sample", check_int("n_neg_sample", self.n_neg_sample, 1))
        self._set("margin", check_float("margin", self.margin, 0.0, strict=True))
        self._set("cache_refresh", check_int("cache_refresh", self.cache_refresh, 0))


@dataclasses.dataclass(frozen=True)
class TrainConfig(Config):
    """Settings of :func:`seqnet.train.train` (defaults: the paper's; see ``seqnet train --help``).

    Attributes:
        seq_len, w: window length L and temporal filter width w (1 <= w <= L; S_1: both 1).
        out_dims: output descriptor dimension (None: the input's, see :meth:`resolve`).
        window: window position, ``"centred"`` or ``"causal"``.
        margin: triplet margin on L2 distances of L2-normalised descriptors.
        optimizer: a key of :data:`OPTIMIZERS`; lr, momentum (SGD only), weight_decay its settings.
        lr_step, lr_gamma: the lr is multiplied by ``lr_gamma`` every ``lr_step`` epochs.
        batch_size: queries per optimiser step; epochs: the last epoch.
        patience: stop after this many epochs without a better val R@1 (None: never).
        stop_inactive: stop after this many epochs in a row without an active triplet (the model no longer
            learns: :func:`seqnet.train.watch.inactive_message` says why and what to change); 0: never.
        n_negatives, n_neg_sample, cache_refresh, pos_radius, neg_radius: see :class:`MiningConfig`
            (radii None: the dataset's, see :meth:`resolve`).
        loss: a key of :data:`~seqnet.train.losses.LOSSES`: ``triplet`` (the paper's), ``seqmatch``
            (SeqMatchNet-style, S_1 only: the margin loss on SeqMatch scores of ``match_len``-frame windows)
            ``vseqmatch`` / ``graph`` (the same on velocity-robust SeqMatch scores / graph path costs).
        match_len: L_m, the window of the framewise losses (and of their validation, ``s1+seqmatch``,
            ``s1+vseqmatch``, ``s1+graph``).
        speed_augment: ``(v_min, v_max)``: every epoch each training query window is re-sampled at a
            speed drawn log-uniformly in that range (:func:`seqnet.sequence.windows.speed_windows`); None: off.
        seed: seeds the model initialisation and the training generator.
        device: torch device (auto: CUDA when present).
        train_split, val_split: dataset splits to train / validate on (``"all"``: the whole dataset;
            val ``"none"``: no validation, best.pt = last.pt).
    """

    seq_len: int = 5
    w: int = 3
    out_dims: int | None = None
    window: str = "centred"
    margin: float = 0.3
    optimizer: str = "sgd"
    lr: float = 1e-4
    momentum: float = 0.9
    weight_decay: float = 1e-3
    lr_step: int = 50
    lr_gamma: float = 0.5
    batch_size: int = 16
    epochs: int = 200
    patience: int | None = None
    stop_inactive: int = 5
    n_negatives: int = 10
    n_neg_sample: int = 1000
    cache_refresh: int = 1000
    pos_radius: float | None = None
    neg_radius: float | None = None
    seed: int = 0
    device: str = "auto"
    train_split: str = "train"
    val_split: str = "val"
    loss: str = "triplet"
    match_len: int = 5
    speed_augment: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        self._set("seq_len", check_int("seq_len", self.seq_len, 1))
        self._set("w", check_int("w", self.w, 1, self.seq_len))
        for key in ("lr_step", "batch_size", "epochs", "n_negatives", "n_neg_sample"):
            self._set(key, check_int(key, getattr(self, key), 1))
        self._set("cache_refresh", check_int("cache_refresh", self.cache_refresh, 0))
        self._set("stop_inactive", check_int("stop_inactive", self.stop_inactive, 0))
        self._set("seed", check_int("seed", self.seed, 0))
        for key in ("out_dims", "patience"):
            if getattr(self, key) is not None:
                self._set(key, check_int(key, getattr(self, key), 1))
        for key in ("lr", "margin", "lr_gamma"):
            self._set(key, check_float(key, getattr(self, key), 0.0, strict=True))
        for key in ("momentum", "weight_decay"):
            self._set(key, check_float(key, getattr(self, key), 0.0))
        self._check_radii()
        optimizer = self.optimizer.lower() if isinstance(self.optimizer, str) else self.optimizer
        self._set("optimizer", check_choice("optimizer", optimizer, OPTIMIZERS))
        check_choice("window", self.window, WINDOW_MODES)
        self._check_loss()
        if not isinstance(self.device, str):
            raise ConfigError(f"device must be a device name (auto, cpu, cuda, cuda:N), got {self.device!r}")
        check_device(self.device)  # validates the device name
        for key in ("train_split", "val_split"):
            value = "none" if key == "val_split" and self.val_split is None else getattr(self, key)
            if not isinstance(value, str) or not value:
                raise ConfigError(f"{key} must be a split name, got {value!r}")
            self._set(key, value)

    def _check_loss(self) -> None:
        self._set("loss", check_choice("loss", self.loss, LOSSES))
        self._set("match_len", check_int("match_len", self.match_len, 1))
        if LOSSES[self.loss].framewise and (self.seq_len, self.w) != (1, 1):
            raise ConfigError(f"the {self.loss} loss trains S_1 (seq_len = w = 1), got seq_len={self.seq_len}, "
                              f"w={self.w} (hint: --seq-len 1 --w 1 --loss {self.loss} --match-len L_m, or "
                              "--loss triplet for S_L)")
        if self.speed_augment is not None:
            self._set("speed_augment", check_speed_range("speed_augment", self.speed_augment))

    @property
    def window_len(self) -> int:
        """The frames of a training query window: ``match_len`` for the framewise (SeqMatch) losses, else
        ``seq_len``."""
        return self.match_len if LOSSES[self.loss].framewise else self.seq_len

    @property
    def ref_pad(self) -> int:
        """Frames a reference window is widened by on either side (the ``vseqmatch`` / ``graph`` losses' paths)."""
        return LOSSES[self.loss].ref_pad(self.window_len)

    def _check_radii(self) -> None:
        for key in ("pos_radius", "neg_radius"):
            if getattr(self, key) is not None:
                self._set(key, check_float(key, getattr(self, key), 0.0, strict=True))
        if self.pos_radius is not None and self.neg_radius is not None:
            check_radii(self.pos_radius, self.neg_radius)

    @property
    def validates(self) -> bool:
        """Whether a val split is used (``val_split`` is not ``"none"``)."""
        return self.val_split.lower() != "none"

    @property
    def mining(self) -> MiningConfig:
        """The mining settings (the radii must be resolved: :meth:`resolve`)."""
        if self.pos_radius is None or self.neg_radius is None:
            raise ConfigError("pos_radius / neg_radius are not resolved (hint: TrainConfig.resolve(dataset))")
        return MiningConfig(self.pos_radius, self.neg_radius, self.n_negatives, self.n_neg_sample, self.margin,
                            self.cache_refresh)

    def resolve(self, ds: Dataset) -> TrainConfig:
        """A copy with the dataset-dependent defaults filled: ``out_dims`` = the input dimension D;
        ``pos_radius`` = ``ds.extra["pos_radius"]``, else the localisation radius; ``neg_radius`` =
        ``ds.extra["neg_radius"]``, else 4 × ``pos_radius``."""
        pos = self.pos_radius or ds.extra.get("pos_radius") or ds.radius
        neg = self.neg_radius or ds.extra.get("neg_radius") or 4 * float(pos)
        return self.merge(out_dims=self.out_dims or ds.query.dim, pos_radius=pos, neg_radius=neg)

    def resumed(self, conf: TrainConfig | None) -> TrainConfig:
        """This (a run's stored, resolved) configuration with the changes ``conf`` may make when
        resuming: only :data:`RESUME_OVERRIDABLE` (epochs, patience, device) may differ."""
        if conf is None:
            return self
        for f in dataclasses.fields(self):
            mine, theirs = getattr(self, f.name), getattr(conf, f.name)
            if f.name not in RESUME_OVERRIDABLE and theirs is not None and theirs != mine:
                raise ConfigError(f"cannot change {f.name!r} when resuming (the run has {mine!r}, got {theirs!r}); "
                                  f"only {', '.join(RESUME_OVERRIDABLE)} may change")
        return dataclasses.replace(self, **{k: getattr(conf, k) for k in RESUME_OVERRIDABLE})


_STORED_MAX = {"seq_len": SEQ_MAX, "w": SEQ_MAX, "match_len": SEQ_MAX, "out_dims": DIM_MAX, "seed": 2**63 - 1}
PATH_MAX = 4096


def stored_config(values: Any, where: str, error: ErrorType = ConfigError) -> dict[str, Any]:
    """A configuration read from a file (a run's ``config.json``, ``joint.json``, a checkpoint's ``"config"``)
    checked before use: a mapping of :class:`TrainConfig` keys (and ``dataset_path``, a path) whose integers
    are in range and that :class:`TrainConfig` accepts (with the CPU for the device, which may be absent
    here); ``error`` naming ``where`` otherwise. Returns a copy of the mapping."""
    if not isinstance(values, Mapping):
        raise error(f"{where}: the stored configuration is not a mapping of settings, got {type(values).__name__}")
    out = dict(values)
    path = out.get("dataset_path")
    if path is not None and (not isinstance(path, str) or not path or len(path) > PATH_MAX or "\x00" in path):
        raise error(f"{where}: dataset_path must be a path, got {str(path)[:60]!r}")
    ints = {f.name for f in dataclasses.fields(TrainConfig) if str(f.type).startswith("int")}
    for key in sorted(ints & set(out)):
        if out[key] is not None:
            number(out[key], f"{where}: {key}", 0, _STORED_MAX.get(key, INDEX_MAX), error)
    device = out.get("device", "auto")
    if not isinstance(device, str) or len(device) > 64:
        raise error(f"{where}: device must be a device name, got {str(device)[:60]!r}")
    try:
        TrainConfig.from_dict({**{k: v for k, v in out.items() if k != "dataset_path"}, "device": "cpu"})
    except (ConfigError, TypeError, ValueError, OverflowError) as e:
        raise error(f"{where}: {' '.join(str(e).split())[:300]}") from e
    return out
