"""The settings of the online localiser (``seqnet localize``): :class:`LocalizeConfig`."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from ..core.config import Config, check_bool, check_choice, check_float, check_int
from ..core.devices import check_device
from ..core.errors import ConfigError
from ..eval.evaluation import single_windows
from ..matching.velocity import ANCHORS
from ..methods.grammar import FUSE_WEIGHT
from ..methods.protocol import Reference
from ..metrics.recall import check_radius
from ..search.precision import PRECISIONS, precision_dtype
from ..sequence.windows import Windows
from .localizer import Localizer, online_method

if TYPE_CHECKING:
    from ..sequence.model import SeqNet

TOP_K = 20  # HVPR's shortlist size K when none is given, chosen or stored in a map


@dataclasses.dataclass(frozen=True)
class LocalizeConfig(Config):
    """Settings of ``seqnet localize``.

    Attributes:
        method: a method name (:mod:`seqnet.methods.grammar`; not ``grh``).
        seq_len: L (None: the S_L model's, else 5); match_len: L_m (None: L).
        top_k: HVPR shortlist size K (None: an index map's stored K, chosen on val or given when it was built, as
            ``seqnet localize --map`` uses it; else :data:`TOP_K`); k: references ranked per frame (for the
            confidence).
        anchor: pivot step of the variable-speed matchers (``end``: as ``seqnet eval --window causal``).
        split: the split replayed (None: test when defined, else all).
        radius: localisation radius (None: the dataset's): correctness and the confidence.
        device: torch device; allow_mismatch: as ``seqnet eval --allow-mismatch``.
        precision: ``float32``, or ``float16`` / ``bfloat16``: the models and the exact searches of every frame
            read and multiply in half precision (half the bytes of a memory-bound step; the map is described in
            float32 first, distances are accumulated in float32).
    """

    method: str = "hvpr"
    seq_len: int | None = None
    match_len: int | None = None
    top_k: int | None = None
    k: int = 20
    anchor: str = "end"
    split: str | None = None
    radius: float | None = None
    fuse_weight: float = FUSE_WEIGHT
    fuse_top_k: int | None = None
    device: str = "auto"
    allow_mismatch: bool = False
    precision: str = "float32"
    RENAMED_KEYS: ClassVar[Mapping[str, str]] = {"rerank_seq_len": "match_len"}  # configs written before 0.3

    def __post_init__(self) -> None:
        self._set("method", online_method(self.method).name)
        self._set("fuse_weight", check_float("fuse_weight", self.fuse_weight, 0.0))
        if self.fuse_top_k is not None:
            self._set("fuse_top_k", check_int("fuse_top_k", self.fuse_top_k, 1))
        for key in ("seq_len", "match_len"):
            if getattr(self, key) is not None:
                self._set(key, check_int(key, getattr(self, key), 1))
        if self.top_k is not None:
            self._set("top_k", check_int("top_k", self.top_k, 1))
        if isinstance(self.k, int) and not isinstance(self.k, bool) and self.k == 1:
            raise ConfigError("k = 1 ranks one reference per frame: the confidence compares the top-1 with the best "
                              "other place ranked (else, as a lower bound, with the last ranked), so it would be 0 "
                              "for every frame; give --k 2 or more (default 20: the more ranked, the more often "
                              "another place is among them)")
        self._set("k", check_int("k", self.k, 1))
        check_choice("anchor", self.anchor, ANCHORS)
        if self.radius is not None:
            self._set("radius", check_radius(self.radius))
        self._set("allow_mismatch", check_bool("allow_mismatch", self.allow_mismatch))
        check_choice("precision", self.precision, PRECISIONS)
        check_device(self.device)

    def windows(self, models: Mapping[str, SeqNet]) -> Windows:
        """The causal windows, resolved once: L (given, else the S_L model's, else 5), L_m (else L), the anchor; a
        single-frame method (``single``, ``s1``) needs none: windows of one frame, so every frame is localised
        and indexed, as ``seqnet eval`` scores it."""
        windows = Windows.resolve(self.seq_len, self.match_len, "causal",
                                  getattr(models.get("seqnet"), "seq_len", None), self.anchor)
        return single_windows(windows) if online_method(self.method).single_frame else windows

    def for_reference(self, reference: Reference) -> LocalizeConfig:
        """These settings with K resolved for ``reference``: ``top_k`` as given, else the K an index map stores for
        the method (:func:`seqnet.maps.chosen.stored`: what ``seqnet localize --map`` and ``serve`` use), else
        :data:`TOP_K`."""
        if self.top_k is not None:
            return self
        from ..maps.chosen import stored

        have = stored(getattr(reference, "meta", None), self.method)
        return self.merge(top_k=int(have.get("top_k", TOP_K)))

    def localizer(self, reference: Reference, radius: float, exact: bool = False) -> Localizer:
        """The :class:`Localizer` of these settings over ``reference`` (described before ``precision`` applies; K
        resolved by :meth:`for_reference`)."""
        half = precision_dtype(self.precision) if self.precision != "float32" else None
        top_k = self.for_reference(reference).top_k
        loc = Localizer(reference, self.method, radius, top_k, self.k, self.fuse_weight, self.fuse_top_k, exact,
                        precision=half)
        for model in loc.models.values():
            if half is not None:
                model.to(half)
            model.pack_taps()  # one window per frame: S_L as w products of contiguous blocks
        return loc


def map_settings(where: str | Path | None, method: str,
                 given: Mapping[str, Any]) -> tuple[dict[str, Any], str | None]:
    """The HVPR settings the index map in ``where`` stores for ``method`` (chosen on val when it was built:
    :mod:`seqnet.maps.chosen`) that ``given`` (``{"top_k": --top-k}``) leaves free, and the line that says which
    were used (to say once the map is loaded); ``({}, None)`` for anything else (a dataset directory, a map without
    the record: the defaults)."""
    from ..core.errors import SeqnetError
    from ..maps.chosen import settings_to_use
    from ..maps.map import read_meta
    from ..maps.store import MAP_JSON

    if where is None or not (Path(where) / MAP_JSON).is_file():
        return {}, None
    try:
        return settings_to_use(read_meta(Path(where)), method, given)
    except (SeqnetError, TypeError, ValueError):
        return {}, None  # a damaged map is refused when it is loaded

