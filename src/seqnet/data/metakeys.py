"""The keys of ``dataset.json``: those seqnet reads (:data:`META_KEYS`, and of the rest, kept as ``Dataset.extra``,
:data:`READ_EXTRA`), a key spelt close to one of them (:func:`misspelt_keys`), and the training radii a dataset
records (:func:`check_extra_radii`)."""

from __future__ import annotations

import difflib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ..core.errors import ConfigError
from ..core.log import warn_once

META_KEYS = {"format", "radius", "position_unit", "splits", "name", "traverses", "provenance", "checksums", "folder"}
READ_EXTRA = {"pos_radius", "neg_radius", "ground_truth"}  # keys of ``extra`` that seqnet reads


def misspelt_keys(meta: Mapping[str, Any], meta_path: Path) -> None:
    """Warn (once per key) of a ``dataset.json`` key close to one seqnet reads (``raduis``, ``position_units``):
    kept as metadata and never read, so its value would go unused without a word."""
    known = sorted(META_KEYS | READ_EXTRA)
    for key in meta:
        near = [] if key in known else difflib.get_close_matches(str(key), known, 1, 0.8)
        if near:
            warn_once(("misspelt", str(meta_path), key), "%s: key %r is not one seqnet reads (kept as metadata, "
                      "unused); did you mean %r?", meta_path, key, near[0])


def check_extra_radii(extra: Mapping[str, Any]) -> None:
    """Refuse (:class:`ConfigError`) training radii recorded with a dataset that training would refuse later:
    ``pos_radius`` above ``neg_radius`` (positives within the one, negatives beyond the other)."""
    p, n = extra.get("pos_radius"), extra.get("neg_radius")
    numbers = all(isinstance(v, int | float) and not isinstance(v, bool) for v in (p, n))
    if numbers and p > n:
        raise ConfigError(f"need pos_radius <= neg_radius, got pos_radius={p:g}, neg_radius={n:g}: training takes "
                          "positives within pos_radius and negatives beyond neg_radius, and would refuse this dataset "
                          "(hint: --pos-radius / --neg-radius, in the dataset's position unit, the two swapped?)")
