"""A learned method on a ``seqnet train --pca`` dataset compared with its model-free counterparts on the unreduced
descriptors too (seqnet.eval.notices.unreduced): the 51a M2 case, where the PCA alone cost raw+seqmatch 0.953 ->
0.837 and s1+seqmatch 0.930 looked like a win."""

from __future__ import annotations

import torch

from seqnet.data.io import load_dataset, save_dataset
from seqnet.eval.config import EvalConfig
from seqnet.eval.evaluate import evaluate
from seqnet.pipelines.pca import main as reduce_main
from seqnet.sequence.model import SeqNet

METHODS = ("single", "s1", "raw+seqmatch", "s1+seqmatch")


def _s1(dim: int) -> SeqNet:
    torch.manual_seed(0)
    return SeqNet(dim, dim, 1, 1)


def test_the_counterparts_are_scored_on_the_unreduced_dataset_on_the_same_queries(tmp_path, synth_dataset):
    raw = save_dataset(synth_dataset, tmp_path / "ds")
    reduced = reduce_main(raw, 2)
    ds = load_dataset(reduced)
    conf = EvalConfig(methods=METHODS, seq_len=3, device="cpu")
    methods = evaluate(ds, conf, {"s1": _s1(2)}, source=reduced).results["methods"]
    plain = evaluate(load_dataset(raw), EvalConfig(methods=("single", "raw+seqmatch"), seq_len=3, device="cpu"))
    for name in ("single", "raw+seqmatch"):
        there = methods[name]["unreduced"]
        assert there["dataset"] == str(raw) and there["dims"] == [16, 2]
        assert there["queries"] == methods[name]["queries"] == plain.results["methods"][name]["queries"]
        assert there["recall@1"] == plain.results["methods"][name]["recall@1"]
    assert "unreduced" not in methods["s1"] and "unreduced" not in methods["s1+seqmatch"]


def test_nothing_more_without_a_reduction_or_a_learned_method(tmp_path, synth_dataset):
    """An unreduced dataset, a reduced one evaluated without learned methods, or without its directory: no second
    evaluation, nothing added."""
    raw = save_dataset(synth_dataset, tmp_path / "ds")
    conf = EvalConfig(methods=METHODS, seq_len=3, device="cpu")
    res = evaluate(load_dataset(raw), conf, {"s1": _s1(16)}, source=raw).results
    assert not any("unreduced" in e for e in res["methods"].values())
    reduced = reduce_main(raw, 2)
    free = evaluate(load_dataset(reduced), EvalConfig(methods=("single", "raw+seqmatch"), seq_len=3, device="cpu"),
                    source=reduced).results
    assert not any("unreduced" in e for e in free["methods"].values())
    loaded = load_dataset(reduced)
    loaded.path = None  # a dataset whose directory is not known (built in memory): nothing to compare with
    api = evaluate(loaded, conf, {"s1": _s1(2)}).results
    assert not any("unreduced" in e for e in api["methods"].values())


def test_the_api_finds_the_unreduced_dataset_as_the_cli_does(tmp_path, synth_dataset):
    """Own-data hostile 52 M1: evaluate(load_dataset(reduced), conf, models) without source= dropped the note the
    CLI gives (the PCA alone cost single 0.280 -> 0.120): load_dataset's directory is the default source."""
    raw = save_dataset(synth_dataset, tmp_path / "ds")
    reduced = reduce_main(raw, 2)
    conf = EvalConfig(methods=METHODS, seq_len=3, device="cpu")
    given = evaluate(load_dataset(reduced), conf, {"s1": _s1(2)}, source=reduced).results
    found = evaluate(load_dataset(reduced), conf, {"s1": _s1(2)}).results
    assert found["methods"]["single"]["unreduced"] == given["methods"]["single"]["unreduced"]
    assert found.get("learned_below_baseline") == given.get("learned_below_baseline")
    assert found["config"]["dataset_path"] == str(reduced)
    split = evaluate(load_dataset(reduced).split("test"), conf, {"s1": _s1(2)}).results  # a split: its source's
    assert split["methods"]["single"]["unreduced"] == given["methods"]["single"]["unreduced"]
