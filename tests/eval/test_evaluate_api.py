"""seqnet.evaluate (the Python API) does what seqnet eval does, minus the files: it evaluates conf.split (test by
default when the dataset defines it), calibrates with target_precision, and says the same warnings (logged, and in
the results); a split of a dataset is evaluated whole; repr is one line; the descriptors evaluated are recorded."""

from __future__ import annotations

import dataclasses
import json
import logging
import subprocess
import sys

import numpy as np
import pytest

from seqnet.core.errors import ConfigError
from seqnet.data.io import load_dataset, save_dataset
from seqnet.data.positives import Positives
from seqnet.data.synth import make_synthetic
from seqnet.eval.evaluate import EvalConfig, evaluate
from seqnet.eval.evaluate import main as eval_main
from seqnet.eval.score import score

METHODS = ("single", "raw+seqmatch")


def numbers(ev):
    return {m: (r["recall@1"], r["queries"]) for m, r in ev.results["methods"].items()}


def clear():
    """A synthetic dataset on which single-frame R@1 means something (little noise), with splits."""
    return make_synthetic(places=200, dim=16, noise=0.05, nuisance=0.0, seed=1)


def shifted(ds, shift: int):
    """``ds`` with explicit positives ``shift`` frames off each query's nearest reference by position."""
    d = np.linalg.norm(ds.query.positions[:, None] - ds.reference.positions[None], axis=-1)
    near = d.argmin(axis=1) + shift
    return dataclasses.replace(ds, positives=Positives.from_lists([[int(r)] if 0 <= r < len(ds.reference) else []
                                                                   for r in near]))


def test_the_split_asked_for_is_the_split_evaluated(synth_dataset):
    conf = EvalConfig(methods=METHODS, ks=(1, 5))
    test = evaluate(synth_dataset.split("test"), conf)  # the README's form: the numbers it always gave
    assert numbers(test) == numbers(score(synth_dataset.split("test"), conf))
    assert test.results["config"]["split"] == "test"  # the split given, named as in the dataset it came from
    for asked in ("test", None):  # None: test, as seqnet eval
        ev = evaluate(synth_dataset, conf.replace(split=asked))
        assert numbers(ev) == numbers(test) and ev.results["config"]["split"] == "test"
    val = evaluate(synth_dataset, conf.replace(split="val"))
    assert numbers(val) == numbers(score(synth_dataset.split("val"), conf))
    assert evaluate(synth_dataset, conf.replace(split="all")).results["methods"]["single"]["queries"] == \
        len(synth_dataset.query)


def test_a_split_is_refused_where_the_dataset_defines_none(synth_dataset):
    with pytest.raises(ConfigError, match=r"split 'val': dataset '.*\[test\]' defines no splits.*hint"):
        evaluate(synth_dataset.split("test"), EvalConfig(methods=("single",), split="val"))  # its own name: taken
    with pytest.raises(Exception, match="has no split 'nope'"):
        evaluate(synth_dataset, EvalConfig(methods=("single",), split="nope"))
    part = evaluate(synth_dataset.split("test"), EvalConfig(methods=("single",), split="0:20"))  # a range: fine
    assert part.results["methods"]["single"]["queries"] == 20


def test_target_precision_calibrates_as_the_cli_does(synth_dir, tmp_path):
    conf = EvalConfig(methods=METHODS, ks=(1, 20), target_precision=0.5)
    ev = evaluate(load_dataset(synth_dir), conf)
    cli = eval_main(conf, synth_dir, None, json=tmp_path / "r.json").data
    for name in METHODS:
        cal = ev.results["methods"][name]["calibrated"]
        assert cal["calibration"]["split"] == "val" and cal == cli["methods"][name]["calibrated"]
    split = evaluate(load_dataset(synth_dir).split("test"), conf)  # the split form: its dataset's val, the same
    assert all(split.results["methods"][n]["calibrated"] == cli["methods"][n]["calibrated"] for n in METHODS)
    moved = load_dataset(synth_dir).split("test")
    moved = dataclasses.replace(moved, query=moved.query.subset(0, 40))  # no longer that split: nothing to calibrate on
    with pytest.raises(ConfigError, match="not a split of dataset .* evaluate the whole dataset"):
        evaluate(moved, conf)


def test_the_api_says_what_the_cli_says(tmp_path, caplog):
    ds = shifted(clear(), 1)
    path = save_dataset(ds, tmp_path / "ds")
    conf = EvalConfig(methods=METHODS, ks=(1, 5, 10_000), radius=50.0, split="test")
    cli = eval_main(conf, path, None, json=tmp_path / "r.json").data
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        ev = evaluate(ds, conf)
    assert ev.results["warnings"] == cli["warnings"] and len(cli["warnings"]) == 3, cli["warnings"]
    assert any("positives look shifted by -1" in w for w in ev.results["warnings"])
    assert [r.getMessage() for r in caplog.records] == ev.results["warnings"]
    assert ev.results["learned_below_baseline"] == cli["learned_below_baseline"]
    assert numbers(ev) == numbers(cli_view(cli))


def cli_view(results):
    return type("R", (), {"results": results})


def test_correct_data_stay_silent(synth_dataset, caplog):
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        ev = evaluate(clear(), EvalConfig(methods=METHODS, split="test"))
        evaluate(synth_dataset.split("test"), EvalConfig(methods=(*METHODS, "delta")))
    assert "warnings" not in ev.results and not caplog.records, [r.getMessage() for r in caplog.records]


def test_warnings_show_in_a_plain_script(tmp_path):
    """No logging configured: the warning reaches stderr all the same (Python's last-resort handler)."""
    script = ("import dataclasses, numpy as np\n"
              "from seqnet import EvalConfig, evaluate, make_synthetic\n"
              "from seqnet.data.positives import Positives\n"
              "ds = make_synthetic(places=200, dim=16, noise=0.05, nuisance=0.0, seed=1).split('test')\n"
              "near = np.abs(ds.query.positions[:, None, 0] - ds.reference.positions[None, :, 0]).argmin(1) + 1\n"
              "p = Positives.from_lists([[int(r)] if r < len(ds.reference) else [] for r in near])\n"
              "evaluate(dataclasses.replace(ds, positives=p), EvalConfig(methods=('single', 'raw+seqmatch')))\n")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and "positives look shifted by -1" in out.stderr, out.stderr


def test_a_model_scored_on_its_training_queries_is_said_without_the_directory(tmp_path, caplog):
    from seqnet.cli import main as cli_main
    from seqnet.sequence.checkpoints import load_model

    data = save_dataset(make_synthetic(places=200, dim=8), tmp_path / "ds")
    assert cli_main(["-q", "--threads", "1", "train", "--dataset", str(data), "--seq-len", "1", "--out",
                     str(tmp_path / "run"), "--epochs", "1", "--out-dims", "8", "--n-neg-sample", "50",
                     "--cache-refresh", "40", "--device", "cpu"]) == 0
    models = {"s1": load_model(tmp_path / "run" / "best.pt")}
    ds, conf = load_dataset(data), EvalConfig(methods=("single", "s1"), split="all", device="cpu")
    cli = eval_main(conf, data, None, models=[tmp_path / "run" / "best.pt"], json=tmp_path / "r.json").data
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        ev = evaluate(ds, conf, models)  # no directory: the checkpoint's provenance and query names tell
    assert ev.results["leakage"] == cli["leakage"] and "are training queries of the S_1 model" in cli["leakage"][0]
    assert ev.results["warnings"] == cli["warnings"]  # the epoch chosen on val queries
    assert any("are training queries" in r.getMessage() for r in caplog.records)
    assert "leakage" not in evaluate(ds, conf.replace(split="test"), models).results
    other = dataclasses.replace(ds, query=dataclasses.replace(ds.query, provenance=None), path=None)  # built in
    assert "leakage" not in evaluate(other, conf, models).results  # memory, no provenance: nothing identifies it
    other.path = data  # load_dataset's directory: the checkpoint's record of it finds the training queries
    assert evaluate(other, conf, models).results["leakage"] == cli["leakage"]
    other = dataclasses.replace(other, path=None)
    assert "leakage" not in evaluate(other, conf, models).results



def test_repr_is_one_short_line(synth_dataset):
    ev = evaluate(synth_dataset, EvalConfig(methods=METHODS))
    said = repr(ev)
    assert len(said) < 300 and "\n" not in said and "single R@1" in said and "raw+seqmatch R@1" in said, said
    assert "dataset 'synthetic[test]', split 'test'" in said


def test_the_descriptors_evaluated_are_recorded(synth_dataset):
    ev = evaluate(synth_dataset, EvalConfig(methods=("single",)))
    prov = synth_dataset.query.provenance
    rec = ev.results["descriptors"]
    assert rec["query"] == rec["reference"] == {"kind": "synthetic", "method": None, "views": None, "size": None,
                                                "pca": None, "dim": synth_dataset.query.dim,
                                                "provenance": prov["id"]}
    described = {"method": "pixels", "size": "native", "crop_bottom": 0, "patch": 8, "views": ["raw", "equalize"]}
    q = dataclasses.replace(synth_dataset.query, provenance={"kind": "describe", "settings": described, "id": "abc"})
    r = dataclasses.replace(synth_dataset.reference, provenance=None)  # unknown: the dataset's describe record
    ds = dataclasses.replace(synth_dataset, query=q, reference=r,
                             extra={"describe": {"method": "pixels", "size": "native"}, "pca": {"dims": 16}})
    rec = evaluate(ds, EvalConfig(methods=("single",), allow_mismatch=True)).results["descriptors"]
    assert rec["query"] == {"kind": "describe", "method": "pixels", "views": ["raw", "equalize"], "size": "native",
                            "pca": 16, "dim": 16, "provenance": "abc"}
    assert rec["reference"] == {"kind": None, "method": "pixels", "views": ["raw"], "size": "native", "pca": 16,
                                "dim": 16, "provenance": None}
    assert json.loads(json.dumps(rec)) == rec


def test_the_default_split_is_said_and_the_split_form_agrees(synth_dataset, caplog):
    """Review M3: evaluate(ds) on a dataset with splits silently scored its test split only (75 of 291 queries),
    and ds.split('test') numbered its queries 0:75 where the whole dataset's form said 216:291. Hostile 52 M6:
    the line was said once per dataset name (a second dataset of the same name heard nothing) and not kept in
    the results."""
    ds = dataclasses.replace(synth_dataset, name="m3-default")
    conf = EvalConfig(methods=METHODS, ks=(1, 5))
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        ev = evaluate(ds, conf)
        again = evaluate(dataclasses.replace(ds), conf)  # another dataset of the same name: said too
    lines = [r.getMessage() for r in caplog.records]
    a, b = ds.ranges("test")["query"]
    assert len(lines) == 2 and f"scoring its test split only (queries {a}:{b}, {b - a} of {len(ds.query)})" in \
        lines[0] and "EvalConfig(split='all')" in lines[0] and lines[0] == lines[1], lines
    assert ev.results["warnings"] == again.results["warnings"] == [lines[0]]
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        given = evaluate(ds, conf.replace(split="test"))
        form = evaluate(ds.split("test"), conf)
        named = evaluate(ds.split("test"), conf.replace(split="test"))  # hostile 52 L4: its own name, accepted
        evaluate(ds, conf.replace(split="all"))
    assert not caplog.records, [r.getMessage() for r in caplog.records]
    for e in (given, form, named):
        assert numbers(e) == numbers(ev) and e.results["config"]["query_range"] == [a, b]
        assert e.results["config"]["split"] == "test"


def test_leakage_is_found_on_a_split_of_the_dataset(tmp_path, caplog):
    """Review M3: evaluate(ds.split('train'), conf, models) found no leakage (the names of a split are not the
    dataset's), where evaluate(ds, split='train') did."""
    from seqnet.cli import main as cli_main
    from seqnet.sequence.checkpoints import load_model

    data = save_dataset(make_synthetic(places=120, dim=8), tmp_path / "ds")
    assert cli_main(["-q", "--threads", "1", "train", "--dataset", str(data), "--seq-len", "1", "--out",
                     str(tmp_path / "run"), "--epochs", "1", "--out-dims", "8", "--n-neg-sample", "20",
                     "--cache-refresh", "40", "--device", "cpu"]) == 0
    models = {"s1": load_model(tmp_path / "run" / "best.pt")}
    ds, conf = load_dataset(data), EvalConfig(methods=("s1",), device="cpu")
    whole = evaluate(ds, conf.replace(split="train"), models)
    split = evaluate(ds.split("train"), conf, models)
    assert whole.results["leakage"] and split.results["leakage"] == whole.results["leakage"]
    assert split.results["config"]["query_range"] == whole.results["config"]["query_range"]
    saved = load_dataset(save_dataset(ds.split("train"), tmp_path / "train"))  # its source is gone: said
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        first = evaluate(saved, conf, models)
        evaluate(saved, conf, models)
    said = [r.getMessage() for r in caplog.records if "cannot be checked" in r.getMessage()]
    assert len(said) == 2 and "is a split whose source is not known here" in said[0], said
    assert said[0] in first.results["warnings"]  # hostile 52 M6: kept in the results too


def test_a_split_with_other_descriptors_is_not_its_source_any_more(synth_dir):
    """Hostile 52 M1: ds.split('test') with its descriptors replaced was still calibrated on its source's val
    (the old descriptors' threshold: precision 0.141 at target 0.8); it is now a dataset of its own."""
    ds = load_dataset(synth_dir)
    conf = EvalConfig(methods=("single",), ks=(1, 5), target_precision=0.8)
    test = ds.split("test")
    assert evaluate(test, conf).results["config"]["query_range"] == list(ds.ranges("test")["query"])
    rng = np.random.default_rng(0)
    proj = rng.standard_normal((ds.query.dim, 16)).astype(np.float32)
    other = dataclasses.replace(test, query=test.query.with_descriptors(test.query.descriptors @ proj),
                                reference=test.reference.with_descriptors(test.reference.descriptors @ proj))
    with pytest.raises(ConfigError, match="not a split of dataset .* evaluate the whole dataset"):
        evaluate(other, conf)  # nothing to calibrate on: never the old descriptors' threshold
    copied = dataclasses.replace(test, query=test.query.with_descriptors(test.query.descriptors.copy()))
    assert evaluate(copied, conf).results["config"]["query_range"] == list(ds.ranges("test")["query"])  # equal


def test_learned_below_baseline_notes_are_said_from_python(synth_dir, tmp_path, caplog, capsys):
    """Hostile 51a L1: evaluate() computed the learned-below notes but never said them; seqnet eval prints them
    under its table (once: not logged there too)."""
    import torch

    from seqnet.cli import main as cli_main
    from seqnet.sequence.checkpoints import save_checkpoint
    from seqnet.sequence.model import SeqNet

    torch.manual_seed(0)
    ds = load_dataset(synth_dir)
    model = SeqNet(ds.reference.dim, 8, 1, 1)  # untrained: below single on the same data
    model.provenance = ds.reference.provenance
    path = save_checkpoint(tmp_path / "s1.pt", model)
    conf = EvalConfig(methods=("single", "s1"), split="test", device="cpu")
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        ev = evaluate(ds, conf, {"s1": model})
    assert ev.results["learned_below_baseline"], ev.results["methods"]
    said = [r.getMessage() for r in caplog.records if "likely:" in r.getMessage()]
    assert len(said) == 1 and said[0].startswith("note: s1"), said
    capsys.readouterr()
    assert cli_main(["--threads", "1", "eval", "--dataset", str(synth_dir), "--model", str(path), "--method",
                     "single,s1", "--split", "test", "--device", "cpu"]) == 0
    out, err = capsys.readouterr()
    assert out.count("likely:") == 1 and "likely:" not in err
