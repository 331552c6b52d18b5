"""Choosing HVPR's K and λ on a validation split: the one-pass grid against a naive loop of evaluations, the
tie rule, settings left as given, each method's own choice whatever else is listed, and a test split that is
never read."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch

from seqnet.data.synth import make_synthetic
from seqnet.eval.evaluate import EvalConfig, evaluate
from seqnet.eval.select import grid_recall, hvpr_grid, pick, select_hvpr
from seqnet.methods.grammar import parse_method
from seqnet.sequence.model import SeqNet

CONF = EvalConfig(methods=("single", "hvpr", "hvpr-fused"), seq_len=5, device="cpu", common_queries=True)


@pytest.fixture(scope="module")
def data():
    torch.manual_seed(0)
    ds = make_synthetic(places=200, dim=16, seed=1)
    return ds, {"seqnet": SeqNet(16, 8, 5, 3), "s1": SeqNet(16, 8, 1, 1)}


def test_the_grid_is_what_evaluate_reports_setting_by_setting(data):
    ds, models = data
    val = ds.split("val")
    ks, ws = (1, 3, 40), (0.0, 0.25, 1.0)
    recall, queries = hvpr_grid(val, models, CONF, "hvpr-fused", ks, ws)
    for i, k in enumerate(ks):
        for j, w in enumerate(ws):  # the naive loop: one whole evaluation per setting
            one = CONF.replace(methods=("hvpr" if w == 0 else "hvpr-fused",), top_k=k, fuse_top_k=k, fuse_weight=w)
            res = evaluate(val, one, models).results["methods"]
            naive = res["hvpr-fused" if w > 0 else "hvpr"]
            assert recall[i, j] == pytest.approx(naive["recall@1"], abs=1e-12), (k, w)
            assert queries == naive["queries"]
    assert len(np.unique(recall)) > 2  # the settings differ: the comparison means something
    shared = "hvpr-single:raw+seqmatch"  # shortlist and re-ranking on one frame descriptor (shared distances)
    recall, _ = hvpr_grid(val, models, CONF, shared, ks, (0.0,))
    for i, k in enumerate(ks):
        naive = evaluate(val, CONF.replace(methods=(shared,), top_k=k), models).results["methods"][shared]
        assert recall[i, 0] == pytest.approx(naive["recall@1"], abs=1e-12), k


def test_grid_recall_matches_a_loop_over_queries(rng):
    m, kmax, lm = 30, 12, 5
    scores, dist = rng.random((m, kmax)) * 10, rng.random((m, kmax))
    scores[:, 3] = scores[:, 4]  # ties: the first in shortlist order wins
    hits, keep = rng.random((m, kmax)) < 0.2, rng.random(m) < 0.8
    ks, ws = (1, 4, 12, 50), (0.0, 0.5, 3.0)
    got = grid_recall(scores, dist, hits[keep], keep, lm, ks, ws)
    for i, k in enumerate(ks):
        for j, w in enumerate(ws):
            correct = []
            for q in np.flatnonzero(keep):
                k_ = min(k, kmax)
                s = [np.float32(scores[q, c]) if w == 0 else np.float32(scores[q, c]) / np.float32(lm)
                     + np.float32(w) * np.float32(dist[q, c]) for c in range(k_)]
                best = min(range(k_), key=lambda c: (s[c], c))
                correct.append(hits[q, best])
            assert got[i, j] == pytest.approx(np.mean(correct)), (k, w)


def test_ties_keep_the_default_else_the_smallest_k():
    ks, ws = [10, 20, 50], [0.0, 0.25, 1.0]
    r = np.array([[0.5, 0.9, 0.9], [0.9, 0.9, 0.1], [0.2, 0.2, 0.2]])
    assert pick(r, ks, ws, (20, 0.25)) == (1, 1)  # the default is among the best: kept
    assert pick(r, ks, ws, (50, 0.25)) == (0, 1)  # else the smallest K, then the λ nearest the default's
    r[2, 2] = 0.95
    assert pick(r, ks, ws, (20, 0.25)) == (2, 2)  # a strictly better setting wins over the default


def test_settings_given_stay_and_the_choice_says_why(data):
    ds, models = data
    val = ds.split("val")
    conf = CONF.replace(top_k=7, fuse_top_k=123, fuse_weight=0.3)
    out, choices = select_hvpr(val, models, conf, free=("fuse_weight",))
    assert (out.top_k, out.fuse_top_k) == (7, 123) and [c.method for c in choices] == ["hvpr-fused"]
    assert set(choices[0].settings) == {"fuse_weight"} and {g["top_k"] for g in choices[0].grid} == {123}
    assert "chosen on val" in choices[0].reason and "queries" in choices[0].reason
    same, none = select_hvpr(val, models, conf, free=())
    assert same == conf and none == []
    every, chosen = select_hvpr(val, models, CONF)
    assert [c.method for c in chosen] == ["hvpr", "hvpr-fused"]
    assert every.shortlist_size(parse_method("hvpr")) == every.method_top_k["hvpr"] == chosen[0].settings["top_k"]
    assert every.weight(parse_method("hvpr-fused")) == chosen[1].settings["fuse_weight"]
    assert (every.top_k, every.fuse_weight) == (CONF.top_k, CONF.fuse_weight)  # each method's own, not everyone's
    assert chosen[1].recall == max(g["recall@1"] for g in chosen[1].grid) >= chosen[1].default_recall


def test_the_choice_never_reads_the_test_split(data):
    """The pipeline's entry (hvpr_on_val) gets the whole dataset; poisoning its test range changes nothing."""
    from seqnet.pipelines.nordland64 import Nordland64Config
    from seqnet.pipelines.nordland64.run import hvpr_on_val

    ds, models = data
    conf = Nordland64Config(device="cpu", methods=("hvpr", "hvpr-fused"))
    picked, choices = hvpr_on_val(ds, models, conf)
    (a, b), (c, d) = ds.splits["test"]["query"], ds.splits["test"]["reference"]
    q, r = np.array(ds.query.descriptors), np.array(ds.reference.descriptors)
    noise = np.random.default_rng(5)
    q[a:b], r[c:d] = noise.normal(0, 100, q[a:b].shape), noise.normal(0, 100, r[c:d].shape)
    poisoned = dataclasses.replace(ds, query=dataclasses.replace(ds.query, descriptors=q),
                                   reference=dataclasses.replace(ds.reference, descriptors=r))
    again, choices2 = hvpr_on_val(poisoned, models, conf)
    assert picked.method_top_k and picked.method_fuse_weight
    assert (again.method_top_k, again.method_fuse_weight) == (picked.method_top_k, picked.method_fuse_weight)
    assert [c.grid for c in choices2] == [c.grid for c in choices]


def test_seqnet_eval_chooses_on_val_unless_told(synth_dir, map_models, tmp_path, capsys):
    from seqnet.cli import main as cli_main

    base = ["eval", "--dataset", str(synth_dir), *(a for p in map_models for a in ("--model", str(p))),
            "--method", "s1+seqmatch,hvpr,hvpr-fused", "--device", "cpu"]
    assert cli_main([*base, "--json", str(tmp_path / "a.json")]) == 0
    res = json.loads((tmp_path / "a.json").read_text())
    chosen = res["selection"]["hvpr"]
    assert [c["method"] for c in chosen] == ["hvpr", "hvpr-fused"] and res["config"]["split"] == "test"
    assert res["methods"]["hvpr"]["method"]["top_k"] == chosen[0]["settings"]["top_k"]
    assert res["methods"]["hvpr-fused"]["method"]["fuse_weight"] == chosen[1]["settings"]["fuse_weight"]
    assert res["config"]["method_fuse_weight"] == {"hvpr-fused": chosen[1]["settings"]["fuse_weight"]}
    assert "chosen on the val split" in capsys.readouterr().out
    assert "33 val queries (1 query = 0.03 of R@1): the choice is mostly chance" in res["selection"]["warning"]
    flags = ["--top-k", "7", "--fuse-top-k", "50", "--fuse-weight", "0.5"]
    assert cli_main([*base, *flags, "--json", str(tmp_path / "b.json")]) == 0  # explicit flags win
    res = json.loads((tmp_path / "b.json").read_text())
    assert "selection" not in res and res["methods"]["hvpr"]["method"]["top_k"] == 7
    assert (res["config"]["fuse_top_k"], res["config"]["fuse_weight"]) == (50, 0.5)
    assert cli_main([*base, "--split", "val", "--json", str(tmp_path / "c.json")]) == 0  # val itself: nothing chosen
    assert "selection" not in json.loads((tmp_path / "c.json").read_text())
    assert cli_main([*base, "--split", "all", "--json", str(tmp_path / "d.json")]) == 0  # all holds val: not chosen
    res = json.loads((tmp_path / "d.json").read_text())
    assert res["selection"]["hvpr"] == [] and "holds val queries" in res["selection"]["not_chosen"]
    assert res["config"]["top_k"] == 20 and res["config"]["fuse_weight"] == 0.25  # the defaults
    assert res["config"]["method_top_k"] is None


ORDERED = ("hvpr", "hvpr-delta:raw+seqmatch", "hvpr-single", "hvpr-fused", "hvpr-fused:raw+seqmatch")


def test_each_method_gets_its_own_choice_whatever_else_is_listed(data):
    """A method's K (and λ) chosen on val, and so its test R@1, are the same alone, listed first or listed last."""
    ds, models = data
    val, test = ds.split("val"), ds.split("test")
    runs = {}
    for methods in [(m,) for m in ORDERED] + [ORDERED, ORDERED[::-1]]:
        conf, choices = select_hvpr(val, models, CONF.replace(methods=methods))
        assert [c.method for c in choices] == list(methods)  # one choice per method, said in the order listed
        res = evaluate(test, conf, models).results["methods"]
        runs[methods] = {m: (res[m]["method"]["top_k"], res[m]["method"].get("fuse_weight"), res[m]["recall@1"],
                             next(c.reason for c in choices if c.method == m)) for m in methods}
    for m in ORDERED:
        assert runs[(m,)][m] == runs[ORDERED][m] == runs[ORDERED[::-1]][m], m
    assert len({runs[(m,)][m][0] for m in ORDERED[:3]}) > 1  # the plain methods' Ks differ: the test means something


def test_choosing_loads_the_dataset_and_the_models_once(synth_dir, map_models, tmp_path, monkeypatch):
    """The choice on val runs on the dataset and models the evaluation loads: one load of each, not two."""
    import seqnet.data.io as io
    import seqnet.sequence.checkpoints as checkpoints
    from seqnet.cli import main as cli_main

    calls = {"dataset": 0, "models": 0}
    real_ds, real_models = io.load_dataset, checkpoints.load_models

    def count(name, fn):
        def inner(*a, **k):
            calls[name] += 1
            return fn(*a, **k)
        return inner

    monkeypatch.setattr(io, "load_dataset", count("dataset", real_ds))
    monkeypatch.setattr(checkpoints, "load_models", count("models", real_models))
    argv = ["eval", "--dataset", str(synth_dir), *(a for p in map_models for a in ("--model", str(p))),
            "--method", "hvpr,hvpr-fused", "--device", "cpu", "--json", str(tmp_path / "a.json")]
    assert cli_main(argv) == 0
    assert json.loads((tmp_path / "a.json").read_text())["selection"]["hvpr"]  # chosen on val
    assert calls == {"dataset": 1, "models": 1}


def test_seqnet_eval_says_each_methods_choice_and_an_explicit_k_is_everyones(synth_dir, map_models, tmp_path, capsys):
    from seqnet.cli import main as cli_main

    base = ["eval", "--dataset", str(synth_dir), *(a for p in map_models for a in ("--model", str(p))),
            "--device", "cpu"]
    pair = ("hvpr-delta:raw+seqmatch", "hvpr")
    out = {}
    for i, methods in enumerate((pair, pair[::-1], pair[:1], pair[1:])):
        capsys.readouterr()
        assert cli_main([*base, "--method", ",".join(methods), "--json", str(tmp_path / f"{i}.json")]) == 0
        res, said = json.loads((tmp_path / f"{i}.json").read_text()), capsys.readouterr().out
        sel = {c["method"]: c for c in res["selection"]["hvpr"]}
        assert list(sel) == list(methods) and all(sel[m]["reason"] in said for m in methods)  # one line each
        for m in methods:
            assert res["config"]["method_top_k"][m] == sel[m]["settings"]["top_k"] == res["methods"][m]["method"][
                "top_k"]
            out.setdefault(m, []).append((sel[m]["settings"], res["methods"][m]["recall@1"]))
    assert all(len(set(map(str, v))) == 1 for v in out.values()), out  # alone or listed with the other, either order
    assert cli_main([*base, "--method", ",".join(pair), "--top-k", "7", "--json", str(tmp_path / "k.json")]) == 0
    res = json.loads((tmp_path / "k.json").read_text())
    assert "selection" not in res and {res["methods"][m]["method"]["top_k"] for m in pair} == {7}


def test_a_methods_own_settings_are_checked_and_used_for_it_only():
    from seqnet.core.errors import ConfigError

    conf = EvalConfig(method_top_k={"hvpr-delta-orig:raw+seqmatch": 50, "hvpr-fused": 100},
                      method_fuse_weight={"hvpr-fused": 1.0})
    assert conf.method_top_k == {"hvpr-delta-paper:raw+seqmatch": 50, "hvpr-fused": 100}  # canonical names
    sizes = {n: conf.shortlist_size(parse_method(n)) for n in ("hvpr-delta-paper:raw+seqmatch", "hvpr",
                                                                "hvpr-fused", "hvpr-fused:raw+seqmatch")}
    assert sizes == {"hvpr-delta-paper:raw+seqmatch": 50, "hvpr": 20, "hvpr-fused": 100, "hvpr-fused:raw+seqmatch": 200}
    assert (conf.weight(parse_method("hvpr-fused")), conf.weight(parse_method("hvpr-fused:raw+seqmatch")),
            conf.weight(parse_method("hvpr"))) == (1.0, 0.25, 0.0)
    assert EvalConfig.from_dict(conf.to_dict()) == conf and EvalConfig(method_top_k={}).method_top_k is None
    for bad in ({"method_top_k": {"single": 5}}, {"method_top_k": {"hvpr": 0}}, {"method_top_k": [("hvpr", 5)]},
                {"method_fuse_weight": {"hvpr": 0.5}}, {"method_fuse_weight": {"hvpr-fused": -1}},
                {"method_top_k": {"nope": 5}}):
        with pytest.raises(ConfigError):
            EvalConfig(**bad)


def test_a_small_val_split_is_said_and_a_large_enough_one_is_not(synth_dir, map_models, tmp_path, caplog,
                                                                  monkeypatch):
    """A choice on fewer than VAL_MIN val queries is made (as training chooses its epoch) and said: a warning line
    and the selection's ``warning``; with enough queries nothing is said."""
    import logging

    from seqnet.cli import main as cli_main
    from seqnet.eval import select

    base = ["eval", "--dataset", str(synth_dir), *(a for p in map_models for a in ("--model", str(p))),
            "--method", "hvpr", "--device", "cpu"]
    caplog.set_level(logging.WARNING, logger="seqnet")
    assert cli_main([*base, "--json", str(tmp_path / "a.json")]) == 0
    res = json.loads((tmp_path / "a.json").read_text())
    assert res["selection"]["hvpr"] and "about 50 or more are needed" in res["selection"]["warning"]
    assert any("mostly chance" in r.getMessage() for r in caplog.records)
    caplog.clear()
    monkeypatch.setattr(select, "VAL_MIN", 33)
    assert cli_main([*base, "--json", str(tmp_path / "b.json")]) == 0
    res2 = json.loads((tmp_path / "b.json").read_text())
    assert "warning" not in res2["selection"] and res2["selection"]["hvpr"] == res["selection"]["hvpr"]
    assert not any("mostly chance" in r.getMessage() for r in caplog.records)


def test_settings_chosen_on_training_queries_are_said(synth_dataset, synth_dir):
    """HVPR's K chosen on val queries that are training queries of a model: said like a calibration on them (it
    was silent); a model trained apart from val stays silent."""
    from types import SimpleNamespace

    from seqnet.eval.select import Choice, training_choice

    choice = [Choice("hvpr", {"top_k": 20}, 0.8, 0.8, [], 30, "")]
    record = {"dataset": str(synth_dir), "split": "0:120", "checkpoint": "r/best.pt"}
    said = training_choice({"s1": SimpleNamespace(trained_on=record)}, synth_dir, synth_dataset, choice)
    assert said == ("HVPR settings of hvpr chosen on the val split (105:141, 36 queries), of which 15 are training "
                    "queries of the S_1 model r/best.pt (0:120): the setting that suits what a model memorised wins "
                    "(hint: give --top-k / --fuse-top-k / --fuse-weight yourself, or rebuild the dataset with a val "
                    "split apart from the training queries)"), said
    apart = {**record, "split": "train"}
    assert training_choice({"s1": SimpleNamespace(trained_on=apart)}, synth_dir, synth_dataset, choice) is None


def test_grid_ks_scores_every_k_past_the_reference_once():
    from seqnet.eval.select import grid_ks

    assert grid_ks({5, 10, 20, 50, 100}, 46, 20) == [5, 10, 20, 50]  # 50 and 100 both re-rank all 46 items
    assert grid_ks({50, 100, 200, 400}, 46, 200) == [200]  # the default kept among them
    assert grid_ks({5, 10, 20, 50, 100}, 296, 20) == [5, 10, 20, 50, 100]  # a longer reference: the grid as it was


def test_k_chosen_on_a_short_val_reference_is_said_against_the_evaluated_one(data):
    """On a val reference shorter than the K grid, K 50 and 100 both meant "no shortlist", and the K carried over
    to a longer evaluated reference was a setting val never scored: scored once, and said with both sizes."""
    from seqnet.eval.select import against, reference_items

    ds, models = data
    val = ds.split("val")
    n = reference_items(val, models, CONF, "hvpr")
    assert n < 50
    _, choices = select_hvpr(val, models, CONF)
    hvpr = next(c for c in choices if c.method == "hvpr")
    ks = sorted({g["top_k"] for g in hvpr.grid})
    assert sum(k >= n for k in ks) == 1 and hvpr.reference_items == n  # 50 and 100: one setting
    assert f"the val reference has {n} items, so every K of {n} or more re-ranks all of them" in hvpr.reason
    longer = make_synthetic(places=1200, dim=16, seed=1).split("test")
    m = reference_items(longer, models, CONF, "hvpr")
    wide = dataclasses.replace(hvpr, settings={"top_k": max(ks)}, reason=hvpr.reason + f", K {max(ks)} too")
    said = against(wide, longer, models, CONF).reason
    assert said.endswith(f"; the evaluated reference has {m} items, where K {max(ks)} is a shortlist that val did "
                         "not score (hint: give --top-k yourself, or build the dataset with a val split whose "
                         "reference has more items than the K grid's largest)"), said
    _, wide_val = select_hvpr(make_synthetic(places=1200, dim=16, seed=1).split("val"), models, CONF)
    assert "val reference has" not in wide_val[0].reason  # hvpr: a val reference past its grid (K <= 100), silent
    assert {g["top_k"] for g in wide_val[0].grid} == {5, 10, 20, 50, 100}


def test_no_val_split_keeps_the_defaults_and_says_so():
    """Without a val split an HVPR's K silently stayed 20 (it capped hvpr-single:raw+seqmatch at 0.768 in the
    hostile test); the defaults kept are said, with what to do."""
    import dataclasses

    from seqnet.data.synth import make_synthetic
    from seqnet.eval.config import EvalConfig
    from seqnet.eval.select import SELECTABLE, choose_on_val

    ds = make_synthetic(places=200, dim=8)
    ds = dataclasses.replace(ds, splits={k: v for k, v in ds.splits.items() if k != "val"})
    conf = EvalConfig(methods=("hvpr", "hvpr-fused", "single"))
    same, said = choose_on_val(ds, "test", {}, conf, SELECTABLE)
    assert same is conf
    assert said == {"selection": {"hvpr": [], "not_chosen": (
        "HVPR settings not chosen: dataset 'synthetic' has no val split to choose them on, so the defaults are kept "
        "(hvpr K 20; hvpr-fused K 200, λ 0.25; hint: give --top-k/--fuse-top-k/--fuse-weight yourself, or rebuild "
        "the dataset with --split val=A:B)")}}
    assert choose_on_val(ds, "val", {}, conf, SELECTABLE) == (conf, None)
