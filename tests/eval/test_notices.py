"""What an evaluation says beside its numbers (seqnet.eval.notices): shifted positives, a moot --radius, no
split named test, trivial K, a model whose epoch was chosen on the evaluated queries; and in results.json."""

from __future__ import annotations

import dataclasses
import json
import logging
from types import SimpleNamespace

import numpy as np

from seqnet.data.io import load_dataset, save_dataset
from seqnet.data.positives import Positives
from seqnet.data.synth import make_synthetic
from seqnet.eval.config import EvalConfig
from seqnet.eval.evaluate import evaluate
from seqnet.eval.evaluate import main as eval_main
from seqnet.eval.notices import (
    few_queries,
    radius_ignored,
    scored_notices,
    selection_leakage,
    shift_notice,
    split_note,
    trivial_ks,
    wilson,
)

METHODS = ("single", "raw+seqmatch")


def with_positives(ds, shift: int):
    """``ds`` with explicit positives: each query's nearest reference by position, listed ``shift`` frames on."""
    d = np.linalg.norm(ds.query.positions[:, None] - ds.reference.positions[None], axis=-1)
    near = d.argmin(axis=1) + shift
    lists = [[int(r)] if 0 <= r < len(ds.reference) else [] for r in near]
    return dataclasses.replace(ds, positives=Positives.from_lists(lists))


def clear():
    """A synthetic dataset on which single-frame R@1 means something (little noise)."""
    return make_synthetic(places=200, dim=16, noise=0.05, nuisance=0.0, seed=1)


def test_one_based_positives_are_said_and_correct_ones_are_not(synth_dataset):
    right = evaluate(with_positives(clear(), 0), EvalConfig(methods=METHODS))
    assert right.results["methods"]["raw+seqmatch"]["recall@1"] > 0.5
    assert shift_notice(right) is None
    shifted = evaluate(with_positives(clear(), 1), EvalConfig(methods=METHODS))
    said = shift_notice(shifted)
    assert said is not None and said.startswith("positives look shifted by -1 (1-based indices?): "), said
    assert "single, raw+seqmatch" in said
    for ds in (synth_dataset, with_positives(synth_dataset, 0)):  # a radius; poor answers on correct positives
        assert shift_notice(evaluate(ds, EvalConfig(methods=METHODS))) is None


def test_the_other_lines():
    assert radius_ignored(None, True) is None and radius_ignored(10.0, False) is None
    said = radius_ignored(10.0, True)
    assert said.startswith("--radius does not change Recall@K with explicit positives") and "use --extra-radius 10" \
        in said
    assert split_note(None, ["train", "test"], 9) is None and split_note("Val", ["Val"], 9) is None
    assert split_note(None, [], 9) is None
    assert split_note(None, ["Train", "Val", "Test"], 200) == \
        "no split named test (splits: Train, Val, Test); scoring all 200 queries — hint: --split Test"
    assert split_note(None, ["a", "b"], 5).endswith("hint: --split NAME (one of a, b) or a range A:B")


def test_trivial_k(synth_dataset):
    ev = evaluate(synth_dataset.split("test"), EvalConfig(methods=("single",), ks=(1, 5, 5000)))
    n = len(ev.view("single").r_items)
    assert trivial_ks(ev, (1, 5)) is None
    assert n < 100 and trivial_ks(ev, EvalConfig().ks) is None  # the default Ks: not the user's choice
    assert trivial_ks(ev, (1, 100)).startswith(f"R@100 (K >= the {n} references indexed)")
    assert trivial_ks(ev, (1, n, n + 1)).startswith(f"R@{n} (K >= the {n} references indexed), R@{n + 1} ")


def test_a_model_whose_epoch_was_chosen_on_the_evaluated_queries(synth_dataset, synth_dir, tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    model = SimpleNamespace(trained_on={"dataset": str(synth_dir), "split": "train",
                                        "checkpoint": str(run / "best.pt")})
    (run / "config.json").write_text(json.dumps({"dataset_path": str(synth_dir), "val_split": "test"}))
    said = selection_leakage({"s1": model}, synth_dir, synth_dataset, "test")
    assert len(said) == 1 and "chose its epoch on ('test'" in said[0], said
    assert "choosing the epoch on the test split makes its test numbers optimistic" in said[0]
    assert selection_leakage({"s1": model}, synth_dir, synth_dataset, "train") == []  # apart from val
    (run / "config.json").write_text(json.dumps({"dataset_path": str(synth_dir), "val_split": "val"}))
    assert selection_leakage({"s1": model}, synth_dir, synth_dataset, "test") == []
    assert "hint: --split test" in selection_leakage({"s1": model}, synth_dir, synth_dataset, "val")[0]
    (run / "config.json").write_text("{not json")
    assert selection_leakage({"s1": model}, synth_dir, synth_dataset, "val") == []  # unreadable: nothing said


def test_results_json_keeps_the_warnings(tmp_path, caplog):
    ds = with_positives(clear(), 1)
    ds = dataclasses.replace(ds, splits={k.capitalize(): v for k, v in ds.splits.items()})
    path = save_dataset(ds, tmp_path / "ds")
    conf = EvalConfig(methods=METHODS, radius=50.0, ks=(1, 1, 5, 10_000))
    assert conf.ks == (1, 5, 10_000)  # a K given twice is one column
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        eval_main(conf, path, tmp_path / "out")
    warnings = json.loads((tmp_path / "out" / "results.json").read_text())["warnings"]
    n = len(load_dataset(path).query)
    expected = [f"no split named test (splits: Train, Val, Test); scoring all {n} queries — hint: --split Test",
                "positives look shifted by -1 (1-based indices?)", "--radius does not change Recall@K",
                "R@10000 (K >= the"]
    for start in expected:
        assert sum(w.startswith(start) for w in warnings) == 1, (start, warnings)
        assert any(r.getMessage().startswith(start) for r in caplog.records), start


def test_the_checkpoint_alone_says_which_queries_chose_its_epoch(synth_dataset, synth_dir, tmp_path):
    alone = tmp_path / "copied" / "best.pt"  # no run directory, no config.json beside it
    record = {"dataset": str(synth_dir), "split": "train", "checkpoint": str(alone), "val_split": "test"}
    a, b = synth_dataset.ranges("test")["query"]
    model = SimpleNamespace(trained_on={**record, "val_queries": [a, a + 5]})  # the range recorded at training
    said = selection_leakage({"s1": model}, synth_dir, synth_dataset, "test")
    assert len(said) == 1 and f"5 of the {b - a} evaluated queries" in said[0] and f"('test', {a}:{a + 5})" in said[0]
    model = SimpleNamespace(trained_on=record)  # written before the range was recorded: the dataset's split
    assert f"('test', {a}:{b})" in selection_leakage({"s1": model}, synth_dir, synth_dataset, "test")[0]
    run = tmp_path / "copied"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"dataset_path": str(synth_dir), "val_split": "test"}))
    model = SimpleNamespace(trained_on={**record, "val_split": "none", "val_queries": None})  # not validated
    assert selection_leakage({"s1": model}, synth_dir, synth_dataset, "test") == []


def test_a_trained_checkpoint_copied_alone_still_warns(tmp_path, caplog):
    import shutil

    from seqnet.cli import main as cli_main
    from seqnet.sequence.checkpoints import load_model

    ds = make_synthetic(places=200, dim=8)
    data = save_dataset(ds, tmp_path / "ds")
    assert cli_main(["-q", "--threads", "1", "train", "--dataset", str(data), "--seq-len", "1", "--val-split", "test",
                     "--out", str(tmp_path / "run"), "--epochs", "1", "--out-dims", "8", "--n-neg-sample", "50",
                     "--cache-refresh", "40", "--device", "cpu"]) == 0
    (tmp_path / "elsewhere").mkdir()
    copy = tmp_path / "elsewhere" / "s1.pt"
    shutil.copy(tmp_path / "run" / "best.pt", copy)
    shutil.rmtree(tmp_path / "run")
    t = load_model(copy).trained_on
    assert t["val_split"] == "test" and t["val_queries"] == list(ds.ranges("test")["query"]), t
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        assert cli_main(["eval", "--dataset", str(data), "--model", str(copy), "--method", "single,s1",
                         "--json", str(tmp_path / "r.json")]) == 0
    said = [r.getMessage() for r in caplog.records]
    assert any(f"are queries the S_1 model {copy} chose its epoch on ('test'" in s for s in said), said
    assert any("chose its epoch on" in w for w in json.loads((tmp_path / "r.json").read_text())["warnings"])


def test_transposed_square_positives_are_said_instead_of_a_shift(tmp_path, caplog):
    """Square positives given as [N_reference, N_query] (VPR_Tutorial's GThard) look like a shift to the top-1s;
    eval says the transposed reading instead of blaming the indices."""
    from data.test_sanity import make

    rng = np.random.default_rng(1)
    places = np.cumsum(rng.normal(size=(80, 16)), axis=0).astype(np.float32)
    seen = places + rng.normal(scale=0.3, size=places.shape).astype(np.float32)
    ref = np.roll(places, -5, axis=0)  # reference j shows place j + 5: query i matches reference i - 5
    rows = [(i, j) for i in range(80) for j in (i - 6, i - 5, i - 4) if 0 <= j < 80]
    given = Positives.from_pairs(np.array([j for _, j in rows]), np.array([i for i, _ in rows]), 80)  # transposed
    path = save_dataset(make(ref, seen, positives=given), tmp_path / "ds")
    with caplog.at_level(logging.WARNING, logger="seqnet"):
        eval_main(EvalConfig(methods=METHODS), path, tmp_path / "out")
    warnings = json.loads((tmp_path / "out" / "results.json").read_text())["warnings"]
    assert any(w.startswith("the positives read better transposed") for w in warnings), warnings
    assert not any("look shifted" in w for w in warnings)


def test_few_scored_queries_get_a_note_with_their_intervals():
    assert few_queries({"single": (30, 0.5)}) is None and few_queries({}) is None
    assert few_queries({"single": (0, 0.0)}) is None  # nothing scored: the table says so
    said = few_queries({"single": (6, 0.0)})
    assert said.startswith("only 6 queries scored: one query changes R@1 by 1/6 = 0.167; 95% intervals of R@1 "
                           "(Wilson): single 0.000 in 0.000-0.390"), said
    both = few_queries({"single": (6, 0.5), "raw+seqmatch": (2, 1.0)})
    assert both.startswith("only 2 to 6 queries (by method) scored: one query changes R@1 by up to 1/2 = 0.500")
    assert "single 0.500 in 0.188-0.812" in both and "raw+seqmatch 1.000 in 0.342-1.000" in both, both
    lo, hi = wilson(0.5, 100)
    assert abs(lo - 0.404) < 1e-3 and abs(hi - 0.596) < 1e-3


def test_scored_notices_are_evals_for_another_stage(synth_dataset, synth_dir):
    """No split named test and training queries: the lines eval says, for a stage scoring queries as it does."""
    import dataclasses

    ds = dataclasses.replace(synth_dataset, splits={"train": synth_dataset.splits["train"]})
    model = SimpleNamespace(trained_on={"dataset": str(synth_dir), "split": "train", "checkpoint": "run/best.pt",
                                        "val_split": "none"})
    said = scored_notices(None, ds, "all", {"s1": model}, synth_dir)
    n, (a, b) = len(ds.query), ds.ranges("train")["query"]
    assert said[0] == f"no split named test (splits: train); scoring all {n} queries — hint: --split NAME (one of " \
        "train) or a range A:B", said
    assert len(said) == 2 and said[1].startswith(f"{b - a} of the {n} evaluated queries ('all', 0:{n}) are training "
                                                 "queries of the S_1 model run/best.pt"), said
    assert scored_notices("train", synth_dataset, "test", {}, synth_dir) == []


def test_the_selection_hint_never_repeats_the_evaluated_split(synth_dataset, synth_dir):
    """An epoch chosen on queries inside test, test evaluated: the hint said ``--split test`` (the split in use);
    it now says to retrain apart from test, or names queries free of the model's training and selection ones."""
    a, b = synth_dataset.ranges("test")["query"]
    record = {"dataset": str(synth_dir), "split": "train", "checkpoint": "r/best.pt", "val_split": f"{a}:{a + 30}",
              "val_queries": [a, a + 30]}
    said = selection_leakage({"s1": SimpleNamespace(trained_on=record)}, synth_dir, synth_dataset, "test")
    assert len(said) == 1 and "--split test" not in said[0], said
    assert said[0].endswith(f"hint: retrain with --train-split / --val-split apart from the test split ({a}:{b}), "
                            "or evaluate queries free of the models' training and epoch-selection ones: --split "
                            "val (EvalConfig(split='val') in Python)"), said


def test_selection_leakage_counts_the_queries_kept_by_resample_every(synth_dataset, synth_dir):
    a, b = synth_dataset.ranges("test")["query"]
    model = SimpleNamespace(trained_on={"dataset": str(synth_dir), "split": "train", "checkpoint": "r/best.pt",
                                        "val_split": "test", "val_queries": [a, a + 10]})
    said = selection_leakage({"s1": model}, synth_dir, synth_dataset, "test", every=3)
    kept = range(a, b, 3)
    assert said[0].startswith(f"{sum(q < a + 10 for q in kept)} of the {len(kept)} evaluated queries ('test', "
                              f"every 3rd of {a}:{b})"), said


def test_a_shortlist_of_every_reference_is_said(synth_dataset):
    """``--top-k 500`` on fewer references was labelled ``top-500`` with no word that it re-ranks them all."""
    import torch

    from seqnet.sequence.model import SeqNet

    torch.manual_seed(0)
    models = {"seqnet": SeqNet(16, 8, 5, 3), "s1": SeqNet(16, 8, 1, 1)}
    test = synth_dataset.split("test")
    conf = EvalConfig(methods=("hvpr", "hvpr-fused"), seq_len=5, device="cpu", top_k=500, fuse_top_k=7,
                      fuse_weight=0.0)
    ev = evaluate(test, conf, models)
    n = len(ev.view("hvpr").r_items)
    assert trivial_ks(ev, EvalConfig().ks) == (
        f"hvpr (K 500 >= the {n} references indexed): the shortlist holds every reference, so it re-ranks them all; "
        "hint: --top-k below the references for a shortlist")
    ev = evaluate(test, conf.replace(top_k=n - 1, fuse_top_k=n), models)
    assert trivial_ks(ev, EvalConfig().ks).endswith("hint: --fuse-top-k below the references for a shortlist")
    assert trivial_ks(evaluate(test, conf.replace(top_k=5, fuse_top_k=5), models), EvalConfig().ks) is None


def test_the_default_ks_note_their_trivial_columns_after_the_table(synth_dir, tmp_path, capsys):
    """The default Ks on a split of fewer references than R@20 / R@100: a note after the table names those columns
    (not a warning: the user chose no K) and is kept in the results; an explicit --ks warns as before."""
    from seqnet.cli import main

    assert main(["eval", "--dataset", str(synth_dir), "--split", "test", "--method", "single,raw+seqmatch",
                 "--json", str(tmp_path / "r.json")]) == 0
    out, err = capsys.readouterr()
    res = json.loads((tmp_path / "r.json").read_text())
    notes = [line for line in out.splitlines() if line.startswith("note: R@")]
    assert len(notes) == 1 and notes[0].startswith("note: R@100 is trivial here (K >= the "), notes
    assert "every query with a positive counts as found, so that column says nothing (the default Ks; " \
           "--ks 1,5,10,20 leaves them out)" in notes[0]
    assert res["trivial_ks"] == notes[0].removeprefix("note: ")
    assert not any("trivial" in w for w in res.get("warnings", [])) and "trivial" not in err


def test_the_default_ks_note_is_silent_on_large_splits_and_explicit_ks(synth_dataset):
    from seqnet.eval.notices import default_ks_note

    ev = evaluate(synth_dataset.split("test"), EvalConfig(methods=("single",)))
    assert default_ks_note(ev, (1, 5, 100)) is None  # given Ks: trivial_ks warns instead
    assert default_ks_note(ev, EvalConfig().ks) is not None
    big = evaluate(make_synthetic(places=400, dim=16, seed=2), EvalConfig(methods=("single",)))
    assert len(big.view("single").r_items) > 100 and default_ks_note(big, EvalConfig().ks) is None
