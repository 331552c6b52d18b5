"""Dataset presets: the settings of the paper's datasets, as data.

A preset fixes, for one benchmark, the localisation radius and its unit, the positive / negative
training radii, the split index ranges (when the benchmark defines them by index), the traverses
(and MSLS cities) of each split as the paper uses them, the paper's split sizes (reference / query,
its supplementary Table S1 "Data Splits"), and the sequence defaults of training (window length
L_d and SeqNet kernel w; the paper tests every dataset at L = 5). The traverses, cities and sizes
are what ``seqnet dataset presets`` shows a user choosing which descriptors to convert
(:func:`preset_summary`); the converters read the radii, splits and sequence defaults.
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
        "val_traverses": ["summer", "winter"],
        "test_traverses": ["spring", "fall"],
        "paper_sizes": {"train": [15000, 15000], "val": [3000, 3000], "test": [3000, 3000]},
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
        "paper_sizes": {"train": [2981, 2931], "test": [1574, 1576]},  # no val: the paper uses Brisbane's
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
        "description": "Brisbane City Loop, day (ref) vs night (query); train / val / test from the struct files "
                       "(its val split is the paper's val set for Oxford too)",
        "radius": 20.0,
        "position_unit": "metres",
        "pos_radius": 5.0,
        "neg_radius": 20.0,
        "splits": None,  # geographic, from one struct file per split (the paper's sizes below)
        "train_traverses": ["day", "night"],
        "val_traverses": ["day", "night"],
        "test_traverses": ["day", "night"],
        "paper_sizes": {"train": [12625, 13932], "val": [500, 488], "test": [2858, 2770]},
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
        "val_traverses": ["database", "query"],
        "test_traverses": ["database", "query"],
        "paper_sizes": {"train": [4973, 4474], "val": [4927, 1732], "test": [33000, 18000]},
        "seq_bounds": True,  # sequence bounds files (<city>_<traverse>_seqBounds.txt) are required
        "seq_len": 5,
        "w": 3,
    },
}

# the original code's names (nordland-sw: summer/winter, nordland-sf: spring/fall, one preset: the same splits)
ALIASES = {"oxford": "oxford-v1.0", "nordland-sw": "nordland", "nordland-sf": "nordland", "nordland-fs": "nordland",
           "bcl": "brisbane"}

SPLIT_ORDER = ("train", "val", "test")

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


def preset_summary(name: str) -> str:
    """Two or more lines on preset ``name`` for ``seqnet dataset presets``: radii, L / w, index splits, then
    per split the traverses (reference / query), cities and the paper's sizes (reference / query)."""
    p = get_preset(name)
    splits = ", ".join(f"{k} {a}:{b}" for k, (a, b) in (p.get("splits") or {}).items()) or "from struct files"
    lines = [f"{p['name']}: radius {p['radius']:g} {p['position_unit']}, pos/neg {p['pos_radius']:g}/"
             f"{p['neg_radius']:g}, L={p['seq_len']} w={p['w']}, splits: {splits}", f"    {p['description']}"]
    for split in SPLIT_ORDER:
        parts = []
        if p.get(f"{split}_traverses"):
            parts.append(" / ".join(p[f"{split}_traverses"]))
        if p.get(f"{split}_cities"):
            parts.append("cities " + ", ".join(p[f"{split}_cities"]))
        if split in (p.get("paper_sizes") or {}):
            parts.append("paper {} / {}".format(*p["paper_sizes"][split]))
        if parts:
            lines.append(f"    {split}: {'; '.join(parts)}")
    return "\n".join(lines)
