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


def test_the_choice_figures_are_labelled_the_proxys_and_say_why_they_differ():
    """The proxy fits a chosen state (NetVLAD clusters) on fewer images than the final descriptors: its R@1 are
    labelled the val proxy's, and the reason says the fitting sets (benchmark: 500 against 3300 images, so val
    raw+seqmatch 0.929 in the choice against 0.898 in the Validation line); a state fitted on as many images, or
    none, adds nothing."""
    cands = {"pixels": DescribeConfig(method="pixels", patch=16),
             "netvlad+equalize": DescribeConfig(method="netvlad", views=("raw", "equalize"))}

    def score(d):
        fits = d.method == "netvlad"
        return {"raw+seqmatch": 0.929 if fits else 0.583, "single": 0.3, "queries": 266, "fit_images": 500 * fits}

    _, record = choose_on_val(cands, score, "val places 1660:1930", lambda d: 3300 if d.needs_fit else 0)
    assert record["reason"].startswith("descriptor netvlad+equalize chosen on val places 1660:1930 (266 queries) "
                                       "before training, by the val proxy's model-free raw+seqmatch R@1 0.929 ")
    assert ("against pixels 0.583 (the proxy's figures: its fitted state on 500 images, the final descriptors' on "
            "3300, so their val R@1 differ)") in record["reason"]
    assert record["scores"]["netvlad+equalize"]["fit_images"] == 500
    for final in (lambda d: 500 if d.needs_fit else 0, None):  # the same fitting set, or not said: no note
        _, record = choose_on_val(cands, score, "val", final)
        assert "proxy's figures" not in record["reason"]
    _, record = choose_on_val({"pixels": cands["pixels"]}, score, "val", lambda d: 0)  # fits nothing: no note
    assert "proxy's figures" not in record["reason"]


def test_the_headline_names_the_candidate_its_views_and_d():
    """results.md's headline: the candidate name (the inverse of candidate_describe), the views and D."""
    from seqnet.pipelines.descriptor_choice import CANDIDATES, candidate_describe, candidate_name, descriptor_text

    base = DescribeConfig(size=(128, 64))
    for name in CANDIDATES:
        assert candidate_name(candidate_describe(base, name)) == name
    both = candidate_describe(base, "netvlad+equalize")
    assert descriptor_text(both, 14336) == "`netvlad+equalize` (views raw,equalize, D=14336)"
    assert descriptor_text(candidate_describe(base, "pixels"), 2048) == "`pixels` (D=2048)"
    assert descriptor_text(candidate_describe(base, "gem")) == "`gem`"
    assert descriptor_text(both.replace(views=("equalize", "raw")), 8) == "`netvlad` (views equalize,raw, D=8)"
