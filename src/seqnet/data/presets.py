"""Dataset presets: the settings of the paper's datasets, as data.

A preset fixes, for one benchmark, the localisation radius and its unit, the positive / negative
training radii, the split index ranges (when the benchmark defines them by index), the traverses
used for training and testing, and the sequence defaults (window length L and SeqNet kernel w).
Values follow the SeqNet paper (Garg & Milford, RA-L 2021) and its code (oravus/seqNet): the
struct files are named ``<set>_d-<negative radius>_d2-<positive radius>.db`` for training and
``..._d-<radius>_...`` for testing.

Use :func:`get_preset` to read one; :func:`preset_metadata` gives the ``dataset.json`` keys a
converter stores (``preset``, ``pos_radius``, ``neg_radius``, ``seq_len``, ``w``).
"""

from __future__ import annotations

import copy
from typing import Any

from ..core.errors import ConfigError

PRESETS: dict[str, dict[str, Any]] = {
    "nordland": {
        "description": "Nordland railway (NRK), clean frame list; train summer/winter, test spring/fall",
        "radius": 1.0,
        "position_unit": "frames",
        "pos_radius": 10.0,
        "neg_radius": 40.0,
        # indices into the clean frame list (27592 frames), as in seqNet's get_datasets.py
        "splits": {"train": [0, 15000], "test": [15100, 18100], "val": [18200, 21200]},
        "train_traverses": ["summer", "winter"],
        "test_traverses": ["spring", "fall"],
        "seq_len": 10,
        "w": 5,
    },
    "oxford-v1.0": {
        "description": "Oxford RobotCar 2015-03-17-11-08-44 (ref) vs 2014-12-16-18-44-24 (query), v1.0 split",
        "radius": 10.0,
        "position_unit": "metres",
        "pos_radius": 5.0,
        "neg_radius": 20.0,
        "splits": None,  # from the struct files / splitInds.npz (geographic split)
        "train_traverses": ["2015-03-17-11-08-44", "2014-12-16-18-44-24"],
        "test_traverses": ["2015-03-17-11-08-44", "2014-12-16-18-44-24"],
        "seq_len": 5,
        "w": 3,
    },
    "oxford-pnv": {
        "description": "Oxford RobotCar, PointNetVLAD split (test struct _test_d-25_d2-5.db)",
        "radius": 25.0,
        "position_unit": "metres",
        "pos_radius": 5.0,
        "neg_radius": 20.0,
        "splits": None,
        "train_traverses": ["2015-03-17-11-08-44", "2014-12-16-18-44-24"],
        "test_traverses": ["2015-03-17-11-08-44", "2014-12-16-18-44-24"],
        "seq_len": 5,
        "w": 3,
    },
    "brisbane": {
        "description": "Brisbane City Loop, day (ref) vs night (query); test only",
        "radius": 20.0,
        "position_unit": "metres",
        "pos_radius": 5.0,
        "neg_radius": 20.0,
        "splits": None,
        "train_traverses": None,
        "test_traverses": ["day", "night"],
        "seq_len": 5,
        "w": 3,
    },
    "msls": {
        "description": "Mapillary Street-Level Sequences, one city per struct file, database vs query",
        "radius": 20.0,
        "position_unit": "metres",
        "pos_radius": 5.0,
        "neg_radius": 20.0,
        "splits": None,
        "train_cities": ["melbourne"],
        "val_cities": ["austin"],
        "test_cities": ["amman", "boston", "sf", "copenhagen"],
        "train_traverses": ["database", "query"],
        "test_traverses": ["database", "query"],
        "seq_bounds": True,  # sequence bounds files (<city>_<traverse>_seqBounds.txt) are required
        "seq_len": 5,
        "w": 3,
    },
}

ALIASES = {"oxford": "oxford-v1.0", "nordland-sw": "nordland", "nordland-fs": "nordland", "bcl": "brisbane"}

METADATA_KEYS = ("pos_radius", "neg_radius", "seq_len", "w")


def preset_names() -> list[str]:
    """The preset names (aliases excluded)."""
    return list(PRESETS)


def get_preset(name: str) -> dict[str, Any]:
    """A copy of the preset ``name`` (or one of its aliases); :class:`ConfigError` if unknown."""
    key = ALIASES.get(name, name)
    if key not in PRESETS:
        valid = ", ".join([*PRESETS, *ALIASES])
        raise ConfigError(f"unknown dataset preset {name!r}; valid: {valid}")
    out = copy.deepcopy(PRESETS[key])
    out["name"] = key
    return out


def preset_metadata(name: str) -> dict[str, Any]:
    """The ``dataset.json`` metadata a converter stores for preset ``name``."""
    p = get_preset(name)
    return {"preset": p["name"], **{k: p[k] for k in METADATA_KEYS}}


def preset_splits(name: str, n_ref: int, n_query: int) -> dict[str, dict[str, tuple[int, int]]]:
    """The preset's index splits, for traverses of ``n_ref`` / ``n_query`` frames.

    Raises :class:`ConfigError` when the preset defines no index splits or a range does not fit.
    """
    p = get_preset(name)
    if not p.get("splits"):
        raise ConfigError(
            f"preset {p['name']!r} defines no index splits (its splits come from the struct files); "
            "hint: pass one --db per set (train, val, test)"
        )
    out: dict[str, dict[str, tuple[int, int]]] = {}
    for split, (a, b) in p["splits"].items():
        if b > min(n_ref, n_query):
            raise ConfigError(
                f"preset {p['name']!r}: split {split} {a}:{b} does not fit traverses of {n_ref} (reference) "
                f"and {n_query} (query) frames; hint: give descriptors of the whole frame list"
            )
        out[split] = {"reference": (a, b), "query": (a, b)}
    return out
