"""Presets: the paper's dataset settings as data."""

from __future__ import annotations

import pytest

from seqnet.core.errors import ConfigError
from seqnet.data.presets import PRESETS, get_preset, preset_metadata, preset_splits


def test_nordland_preset_matches_paper():
    p = get_preset("nordland")
    assert p["radius"] == 1 and p["position_unit"] == "frames"
    assert (p["pos_radius"], p["neg_radius"]) == (10, 40)
    assert p["splits"] == {"train": [0, 15000], "test": [15100, 18100], "val": [18200, 21200]}
    assert (p["seq_len"], p["w"]) == (10, 5)
    assert p["train_traverses"] == ["summer", "winter"] and p["test_traverses"] == ["spring", "fall"]


@pytest.mark.parametrize("name,radius", [("oxford-v1.0", 10), ("oxford", 10), ("brisbane", 20), ("msls", 20)])
def test_radii(name, radius):
    p = get_preset(name)
    assert p["radius"] == radius and p["position_unit"] == "metres"
    assert (p["seq_len"], p["w"]) == (5, 3)


def test_every_preset_has_the_keys_converters_need():
    for name in PRESETS:
        meta = preset_metadata(name)
        assert set(meta) == {"preset", "pos_radius", "neg_radius", "seq_len", "w"}
        assert 0 < meta["pos_radius"] < meta["neg_radius"]


def test_get_preset_returns_a_copy():
    get_preset("nordland")["splits"]["train"][1] = 1
    assert PRESETS["nordland"]["splits"]["train"] == [0, 15000]


def test_unknown_preset_names_valid_set():
    with pytest.raises(ConfigError, match="unknown dataset preset 'kitti'.*nordland"):
        get_preset("kitti")


def test_preset_splits():
    s = preset_splits("nordland", 27592, 27592)
    assert s["test"] == {"reference": (15100, 18100), "query": (15100, 18100)}
    with pytest.raises(ConfigError, match="does not fit"):
        preset_splits("nordland", 3000, 3000)
    with pytest.raises(ConfigError, match="no index splits"):
        preset_splits("msls", 100, 100)
