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


def test_a_candidate_names_its_views():
    """``METHOD+VIEW`` is the method's descriptors of the raw and of that view of each image; the benchmark and
    own data offer netvlad+equalize to the val choice, after netvlad (a tie keeps the cheaper)."""
    from seqnet.describe import DescribeConfig
    from seqnet.pipelines.descriptor_choice import CANDIDATES, candidate_describe
    from seqnet.pipelines.nordland64 import Nordland64Config
    from seqnet.pipelines.nordland64.select import candidate_config

    base = DescribeConfig(size=(128, 64), views=("raw", "equalize"))
    assert candidate_describe(base, "netvlad").views == ("raw",)  # a plain name: the method's own view
    both = candidate_describe(base.replace(views=("raw",)), "netvlad+equalize")
    assert (both.method, both.views, both.size) == ("netvlad", ("raw", "equalize"), (128, 64))
    assert CANDIDATES.index("netvlad") < CANDIDATES.index("netvlad+equalize")
    conf = Nordland64Config()
    assert "netvlad+equalize" in conf.descriptors
    assert candidate_config(conf, "netvlad+equalize").views == ("raw", "equalize")
