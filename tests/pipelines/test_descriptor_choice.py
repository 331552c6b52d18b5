"""The descriptor choice on val: a val split too small to choose is said."""

from __future__ import annotations

import logging

from seqnet.describe import DescribeConfig
from seqnet.pipelines.descriptor_choice import choose_on_val


def test_a_choice_on_a_few_val_queries_is_warned(caplog):
    cands = {"pixels": DescribeConfig(method="pixels", patch=16), "pixels8": DescribeConfig(method="pixels", patch=8)}

    def score(queries):
        return lambda d: {"raw+seqmatch": 0.5 + 0.1 * (d.patch == 8), "single": 0.2, "queries": queries, "dim": 4,
                          "seconds": 0.0}

    caplog.set_level(logging.WARNING, logger="seqnet")
    _, record = choose_on_val(cands, score(6), "val")
    assert record["chosen"] == "pixels8" and "chosen on 6 val queries" in record["warning"]
    assert any("mostly chance" in r.getMessage() for r in caplog.records)
    _, record = choose_on_val(cands, score(266), "val")
    assert "warning" not in record
    _, record = choose_on_val({"pixels": cands["pixels"]}, score(6), "val")  # one candidate: nothing was chosen
    assert "warning" not in record
