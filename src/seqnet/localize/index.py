"""Online localisation against an index map (``seqnet index build --window causal``).

An index map (:mod:`seqnet.maps`) already holds what :class:`seqnet.localize.localizer.Localizer` computes
from a reference traverse: the shortlist descriptor of every reference item (and its ANN index) and
the re-ranking descriptor of every reference frame. :class:`IndexLocalizer` reads them instead of
describing raw reference frames, so a map of a million places is prepared once, not per run, and
its shortlist goes through the map's index (HNSW, IVF, ...) unless ``exact``.

The map must use causal windows (the localiser's); its method, its shortlister (k-NN) and its
re-ranker (whole-map matching) can run, with the map's L and L_m and models. With a ``flat`` map
(or ``exact=True``) the estimates equal those of a :class:`~seqnet.localize.localizer.Localizer` over the
dataset the map was built from (``tests/test_localize_index.py``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import numpy as np
import torch

from ..core.errors import ConfigError
from ..eval.evaluate import EvalConfig
from ..maps import Map
from ..maps.evaluate import check_conf
from ..sequence.descriptors import SeqNet
from .localizer import Localizer


@dataclasses.dataclass
class IndexMap:
    """An opened index map with the localisation radius (what :class:`IndexLocalizer` reads)."""

    map: Map
    radius: float
    models: Mapping[str, SeqNet] = dataclasses.field(default_factory=dict)

    @classmethod
    def of(cls, mp: Map, radius: float | None = None) -> IndexMap:
        """``mp`` with ``radius`` (default: the radius of the dataset it was built from)."""
        radius = radius or (mp.meta.get("source") or {}).get("radius")
        if radius is None:
            raise ConfigError(f"map {mp.path} records no localisation radius; give one (--radius)")
        return cls(mp, float(radius), dict(mp.models))

    @property
    def name(self) -> str:
        return str(self.map.path.name)

    @property
    def provenance(self) -> dict | None:
        return self.map.provenance

    @property
    def names(self) -> list[str] | None:
        return self.map.names


def index_conf(mp: Map, method: str, conf: EvalConfig | None) -> EvalConfig:
    """``conf`` checked against the map (window, L, L_m, method) and set to the map's L and L_m."""
    if mp.config.window != "causal":
        raise ConfigError(f"map {mp.path} was built with {mp.config.window} windows; the online localiser needs "
                          "causal ones (seqnet index build --window causal)")
    conf = (conf or EvalConfig()).replace(window="causal", methods=(method,))
    check_conf(mp, conf)
    return conf.replace(seq_len=mp.config.length, rerank_seq_len=mp.config.match_len)


class IndexLocalizer(Localizer):
    """:class:`~seqnet.localize.localizer.Localizer` over an :class:`IndexMap` (see the module docstring).

    Args:
        index_map: the map and radius; method: one the map serves; conf, anchor: as the Localizer's;
        exact: shortlist by exact search over the stored descriptors instead of the map's index.
    """

    def __init__(self, index_map: IndexMap, method: str, conf: EvalConfig | None = None, anchor: str = "end",
                 exact: bool = False) -> None:
        self.exact = exact or index_map.map.index is None
        super().__init__(index_map, method, index_conf(index_map.map, method, conf), anchor)

    def _attach(self, ref_map: IndexMap) -> None:  # type: ignore[override]
        mp, m = ref_map.map, self.method
        self.map = mp
        self.ref_items, self.r_pos = mp.items, mp.positions[mp.items]
        r_items = self._array(mp.shortlist) if m.shortlist is not None and self.exact else None
        r_frames = None if m.frames is None else self._array(mp.frames)
        self._prepare(mp.input_dim, r_items, r_frames, mp.match_starts)

    def _array(self, a: np.ndarray) -> torch.Tensor:
        """A map array as float32 on the device (a float32 memory map on the CPU is not copied)."""
        return torch.as_tensor(np.asarray(a, dtype=np.float32), device=self.device)

    def _shortlist(self, q: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
        if self.exact:
            return super()._shortlist(q, k)
        dist, ids = self.map.search(q[None].float().cpu().numpy(), k)
        keep = ids[0] >= 0  # an approximate index may return fewer than k
        return (torch.as_tensor(dist[0][keep], device=self.device),
                torch.as_tensor(ids[0][keep], device=self.device))
