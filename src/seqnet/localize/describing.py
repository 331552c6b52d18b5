"""The map's describer, rebuilt for query images: only one without fitted state, and no code a file names."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import ConfigError
from ..core.provenance import check_same
from ..methods.protocol import Reference

if TYPE_CHECKING:
    from ..describe.describer import Describer


def map_describer(ref_map: Reference, allow: bool,
                  describer: str | None = None) -> tuple[Describer, Callable[[np.ndarray, str], None]]:
    """The describer the map was described with (rebuilt from its provenance) and ``check(descriptors [1, D],
    what)``, which holds the first query descriptors' provenance to the map's (a call after one that passed returns
    at once: a stream may call it on every frame). A plug-in describer the map's
    files name is imported only when the user names the same one (``describer``, ``--describer``): seqnet runs
    no code a file names."""
    from ..describe import DescribeConfig, make_describer
    from ..describe.stage import describe_provenance

    prov = ref_map.provenance
    if not prov or prov.get("kind") != "describe":
        raise ConfigError("the map's descriptors do not record how they were described (no 'describe' provenance), "
                          "so query images cannot be described alike; describe them yourself and pass the "
                          "descriptor file as --query")
    derived = ("dim", "whiten", "describer_provenance")  # not options: the PCA's, a plug-in module's own
    settings = prov.get("settings") if isinstance(prov.get("settings"), dict) else {}
    check_named_code(settings, describer)
    conf = DescribeConfig.from_dict({k: v for k, v in settings.items() if k not in derived})
    if conf.needs_fit or "dim" in prov["settings"]:
        raise ConfigError(f"the map was described with fitted state ({conf.method}, PCA or clusters), which "
                          "localize cannot rebuild; describe the query images with `seqnet describe` using the "
                          "map's fitted state and pass the descriptor file as --query")

    checked: list[bool] = []

    def check(first: np.ndarray, what: str) -> None:
        if checked:  # one describer's outputs share their provenance: checked (or warned about) once
            return
        check_same(prov, describe_provenance(conf, None, first), "the map's descriptors", what, allow)
        checked.append(True)

    return make_describer(conf), check


def check_named_code(settings: Mapping[str, object], describer: str | None) -> None:
    """Refuse to rebuild a describer that would run code or read a file named in the map's files: a plug-in
    module (unless the user names the same one with ``--describer``) or a NetVLAD checkpoint."""
    named = settings.get("describer")
    if named and named != describer:
        raise ConfigError(f"the map's descriptors were made by the plug-in describer {str(named)[:80]!r}, named in the "
                          "map's files; seqnet imports no code a file names: pass --describer "
                          f"{str(named)[:80]} if you trust that module")
    if settings.get("checkpoint"):
        raise ConfigError("the map was described with a checkpoint named in its files, which localize does not open; "
                          "describe the query images with `seqnet describe` and that checkpoint, and pass the "
                          "descriptor file as --query")
