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


@pytest.mark.parametrize("alias", ["nordland-sf", "nordland-fs", "nordland-sw"])
def test_original_code_nordland_names_are_aliases(alias):
    assert get_preset(alias) == get_preset("nordland") and preset_metadata(alias)["preset"] == "nordland"


def test_cli_from_seqnet_accepts_nordland_sf(tmp_path, capsys):
    import numpy as np

    from seqnet.cli import main
    from seqnet.data.io import load_dataset

    rng = np.random.default_rng(0)
    for side in ("spring", "fall"):
        np.save(tmp_path / f"{side}.npy", rng.random((21300, 4), dtype=np.float32))
    rc = main(["dataset", "from-seqnet", "--preset", "nordland-sf", "--ref-desc", str(tmp_path / "spring.npy"),
               "--query-desc", str(tmp_path / "fall.npy"), "--out", str(tmp_path / "ds")])
    assert rc == 0
    ds = load_dataset(tmp_path / "ds")
    assert ds.extra["preset"] == "nordland" and ds.splits["test"]["query"] == (15100, 18100)


def test_brisbane_trains_and_validates_as_the_paper():
    p = get_preset("brisbane")
    assert p["train_traverses"] == p["val_traverses"] == p["test_traverses"] == ["day", "night"]
    assert p["paper_sizes"] == {"train": [12625, 13932], "val": [500, 488], "test": [2858, 2770]}
    assert "val" not in get_preset("oxford")["paper_sizes"]  # Oxford is validated on Brisbane's val set


def test_every_traverse_city_and_size_field_is_shown_by_the_listing(capsys):
    from seqnet.cli import main

    assert main(["dataset", "presets"]) == 0
    out = capsys.readouterr().out
    for p in PRESETS.values():
        for key, value in p.items():
            if key.endswith(("_traverses", "_cities")):
                assert " / ".join(value) in out or ", ".join(value) in out, key
        for a, b in (p.get("paper_sizes") or {}).values():
            assert f"paper {a} / {b}" in out
    assert "    val: database / query; cities austin; paper 4927 / 1732" in out.splitlines()
    known = {"description", "radius", "position_unit", "pos_radius", "neg_radius", "splits", "seq_len", "w",
             "seq_bounds", "paper_sizes", *(f"{s}_{k}" for s in ("train", "val", "test") for k in ("traverses",
                                                                                                   "cities"))}
    assert {k for p in PRESETS.values() for k in p} <= known  # no field nothing shows or reads


def test_oxford_paper_test_size_is_the_struct_files():
    from conftest import shared_data

    from seqnet.data.structfiles import read_db_struct

    s = read_db_struct(shared_data("seqnet_structfiles") /
                       "oxford-v1.0_2015-03-17-11-08-44_2014-12-16-18-44-24_test_d-10_d2-5.db")
    assert [len(s.db_names), len(s.q_names)] == get_preset("oxford")["paper_sizes"]["test"]
