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
