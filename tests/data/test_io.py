"""The log line of :func:`seqnet.data.io.save_dataset`."""

from __future__ import annotations

import dataclasses
import logging

from seqnet.core.provenance import make
from seqnet.data.io import save_dataset
from seqnet.data.synth import make_synthetic


def test_the_wrote_line_says_how_the_descriptors_were_made(tmp_path, caplog):
    """The method and views beside D (D doubles with two views), or D alone for descriptors of no describer."""
    ds = make_synthetic(places=100, dim=8, seed=0)
    with caplog.at_level(logging.INFO, logger="seqnet"):
        save_dataset(ds, tmp_path / "plain")
    assert (f"wrote dataset {tmp_path / 'plain'} (reference {len(ds.reference)}, query {len(ds.query)} images; "
            "descriptors D=8)") in caplog.messages
    prov = make("describe", {"method": "pixels", "views": ["raw", "equalize"]}, None, 8)
    described = dataclasses.replace(ds, reference=dataclasses.replace(ds.reference, provenance=prov),
                                    query=dataclasses.replace(ds.query, provenance=prov))
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="seqnet"):
        save_dataset(described, tmp_path / "views")
    assert any("descriptors pixels, views raw,equalize, D=8)" in m for m in caplog.messages)


def test_a_misspelt_key_is_said_not_kept_silently(tmp_path, caplog, monkeypatch):
    """A hand-edited dataset.json with "position_units" (or "raduis") kept it as metadata and used the default
    without a word."""
    import json

    import pytest

    import seqnet.core.log
    from seqnet.core.errors import DatasetError
    from seqnet.data.io import load_dataset

    monkeypatch.setattr(seqnet.core.log, "_SAID", set())
    path = save_dataset(make_synthetic(places=100, dim=8), tmp_path / "ds")
    meta = json.loads((path / "dataset.json").read_text())
    meta["position_units"], meta["source_note"] = "metres", "mine"  # a typo, and a key of the user's own
    (path / "dataset.json").write_text(json.dumps(meta))
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        load_dataset(path)
    said = [r.getMessage() for r in caplog.records if "not one seqnet reads" in r.getMessage()]
    assert said == [f"{path / 'dataset.json'}: key 'position_units' is not one seqnet reads (kept as metadata, "
                    "unused); did you mean 'position_unit'?"]
    meta["raduis"] = meta.pop("radius")
    (path / "dataset.json").write_text(json.dumps(meta))
    with caplog.at_level(logging.WARNING, logger="seqnet"), pytest.raises(DatasetError, match="missing key 'radius'"):
        load_dataset(path)
    assert any("'raduis' is not one seqnet reads (kept as metadata, unused); did you mean 'radius'?"
               in r.getMessage() for r in caplog.records)


def test_training_radii_that_training_would_refuse_are_refused_at_build(tmp_path):
    """--pos-radius 50 --neg-radius 10 were written into dataset.json without complaint; seqnet train refused the
    dataset later. Refused before anything is written."""
    import pytest

    from seqnet.core.errors import ConfigError

    ds = make_synthetic(places=100, dim=8)
    bad = dataclasses.replace(ds, extra={**ds.extra, "pos_radius": 50.0, "neg_radius": 10.0})
    with pytest.raises(ConfigError, match=r"need pos_radius <= neg_radius, got pos_radius=50, neg_radius=10: .*"
                                          r"the two swapped\?"):
        save_dataset(bad, tmp_path / "ds")
    assert not (tmp_path / "ds").exists()
    save_dataset(dataclasses.replace(ds, extra={**ds.extra, "pos_radius": 10.0, "neg_radius": 50.0}), tmp_path / "ok")
