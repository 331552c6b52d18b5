"""Settings of a map: what is stored for the shortlist, what for re-ranking, and the ANN index."""

from __future__ import annotations

import dataclasses

from ..core.config import Config, check_bool, check_choice, check_int
from ..core.devices import check_device
from ..core.errors import ConfigError
from ..methods.grammar import FRAME_FEATURES, HVPR_ALIAS, HVPR_RERANK, Method, canonical_name, parse_method
from ..search.ann import AnnConfig
from ..security.limits import SEQ_MAX
from ..sequence.descriptors import SEQUENCE_DESCRIPTORS, descriptor_name
from ..sequence.windows import WINDOW_MODES, WindowSettings

DTYPES = ("float32", "float16")


@dataclasses.dataclass(frozen=True)
class MapConfig(WindowSettings, Config):
    """How a map is built (see ``seqnet index build --help`` and docs/scale.md).

    Attributes:
        shortlist: the shortlisting descriptor of every reference item (a key of
            :data:`SEQUENCE_DESCRIPTORS`, e.g. ``seqnet`` = S_L); an ANN index is built over it.
        rerank: ``<frames>+<matcher>``: the frame descriptors stored for re-ranking and the matcher.
        seq_len: L of the sequence descriptors (None: the S_L model's, else 5).
        match_len: L_m of the matcher (None: L).
        window: ``centred`` or ``causal`` windows (queries must use the same).
        ann: the index over the shortlist descriptors (``flat`` = exact search over the stored descriptors).
        dtype: storage of the descriptor arrays (``float16`` halves the map; computed in float32).
        split: the dataset split whose reference side is mapped (None: test when defined, else all).
        device: torch device for describing the reference.
        allow_mismatch: go on when a model and the descriptors were made differently.
        shards: build an IVF index in this many shards, merged on disk (``index.ivfdata``, opened
            memory-mapped; :mod:`seqnet.maps.shards`); 1: one index in memory.
    """

    shortlist: str = "seqnet"
    rerank: str = HVPR_RERANK
    seq_len: int | None = None
    match_len: int | None = None
    window: str = "centred"
    ann: AnnConfig = AnnConfig()
    dtype: str = "float32"
    split: str | None = None
    device: str = "auto"
    allow_mismatch: bool = False
    shards: int = 1

    def __post_init__(self) -> None:
        self._set("shortlist", descriptor_name(self.shortlist) if isinstance(self.shortlist, str) else self.shortlist)
        check_choice("shortlist descriptor", self.shortlist, SEQUENCE_DESCRIPTORS)
        if isinstance(self.rerank, str):
            self._set("rerank", canonical_name(self.rerank))
        self.method  # noqa: B018 - validates the re-ranker
        for key in ("seq_len", "match_len"):
            if getattr(self, key) is not None:
                self._set(key, check_int(key, getattr(self, key), 1, SEQ_MAX))
        check_choice("window mode", self.window, WINDOW_MODES)
        if not isinstance(self.ann, AnnConfig):
            raise ConfigError(f"ann must be an AnnConfig, got {type(self.ann).__name__}")
        check_choice("map dtype", self.dtype, DTYPES)
        self._set("allow_mismatch", check_bool("allow_mismatch", self.allow_mismatch))
        self._set("shards", check_int("shards", self.shards, 1, 1 << 16))
        check_device(self.device)

    @property
    def method(self) -> Method:
        """The HVPR method the map serves: shortlist by ``shortlist``, re-rank by ``rerank``."""
        name = HVPR_ALIAS if (self.shortlist, self.rerank) == ("seqnet", HVPR_RERANK) else \
            f"hvpr-{self.shortlist}:{self.rerank}"
        return parse_method(name)

    @property
    def frames_descriptor(self) -> str:
        """The key of :data:`SEQUENCE_DESCRIPTORS` computed over each frame for re-ranking."""
        return FRAME_FEATURES[self.method.frames]

    def roles(self) -> set[str]:
        """Model roles the map needs (``seqnet`` = S_L, ``s1`` = S_1)."""
        return self.method.models()
