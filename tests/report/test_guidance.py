"""Learned methods below their model-free counterparts: the notes, on small results dicts."""

from __future__ import annotations

from seqnet.report.guidance import counterparts, format_notes, learned_below_baseline, likely_causes, row_marks
from seqnet.report.tables import format_table


def _results(r1: dict[str, float], queries: int = 100, models: dict | None = None, seq_len: int = 5) -> dict:
    methods = {n: {"recall@1": v, "queries": queries, "method": {"seq_len": seq_len, "models": models or {}}}
               for n, v in r1.items()}
    return {"methods": methods, "config": {"seq_len": seq_len, "models": models or {}}}


def test_the_pairs():
    present = dict.fromkeys(["single", "s1", "smoothing", "delta", "seqnet", "raw+seqmatch", "s1+seqmatch", "hvpr",
                             "hvpr-delta:raw+seqmatch", "hvpr-fused", "raw+seqmatch-rev"])
    assert counterparts("s1", present) == ["single"]
    assert counterparts("seqnet", present) == ["smoothing", "delta"]
    assert counterparts("s1+seqmatch", present) == ["raw+seqmatch"]
    assert counterparts("hvpr", present) == ["raw+seqmatch", "hvpr-delta:raw+seqmatch"]
    assert counterparts("hvpr-fused", present) == ["raw+seqmatch", "hvpr-delta:raw+seqmatch"]
    for model_free in ("single", "delta", "raw+seqmatch", "hvpr-delta:raw+seqmatch", "not a method"):
        assert counterparts(model_free, present) == []


def test_the_issue_case_is_noted_with_its_causes():
    # the issue: s1 0.500 vs single 0.694, hvpr 0.611 vs raw+seqmatch 0.917, on D = 6400, 36 queries
    models = {"seqnet": {"in_dims": 6400, "out_dims": 6400, "seq_len": 5, "w": 3},
              "s1": {"in_dims": 6400, "out_dims": 6400, "seq_len": 1, "w": 1}}
    res = _results({"single": 0.694, "s1": 0.500, "raw+seqmatch": 0.917, "hvpr": 0.611, "seqnet": 0.9,
                    "delta": 0.5}, queries=36, models=models)
    notes = learned_below_baseline(res)
    assert [(n.learned, n.baseline) for n in notes] == [("s1", "single"), ("hvpr", "raw+seqmatch")]
    causes = " ".join(notes[0].causes)
    assert "D = 6400 without PCA" in causes and "--pca" in causes and "36 evaluated queries" in causes
    lines = format_notes(notes)
    assert lines[0].startswith("note: s1 (R@1 0.500) is below the model-free single (0.694)")
    assert row_marks(notes) == {"s1": "learned, below model-free single",
                                "hvpr": "learned, below model-free raw+seqmatch"}


def test_above_equal_or_within_one_query_says_nothing():
    assert learned_below_baseline(_results({"single": 0.70, "s1": 0.80})) == []
    assert learned_below_baseline(_results({"single": 0.70, "s1": 0.70})) == []
    assert learned_below_baseline(_results({"single": 0.705, "s1": 0.70})) == []  # half a query of 100
    assert len(learned_below_baseline(_results({"single": 0.71, "s1": 0.70}))) == 1  # one query
    assert learned_below_baseline(_results({"s1": 0.1})) == []  # no counterpart evaluated
    assert learned_below_baseline({"methods": {}}) == []


def test_a_window_length_mismatch_is_named():
    models = {"seqnet": {"in_dims": 512, "out_dims": 512, "seq_len": 10, "w": 5}}
    causes = likely_causes("seqnet", _results({"seqnet": 0.2, "delta": 0.5}, models=models, seq_len=5))
    assert any("trained on windows of L=10 but evaluated at L=5" in c for c in causes)
    assert not any("without PCA" in c for c in causes)


def test_the_text_table_marks_the_row():
    res = _results({"single": 0.694, "s1": 0.500})
    table = format_table(res["methods"], (1,))
    s1_row = next(line for line in table.splitlines() if line.startswith("s1 "))
    assert "[learned, below model-free single]" in s1_row
    assert "below" not in next(line for line in table.splitlines() if line.startswith("single "))


def test_the_html_report_has_a_notes_section_only_when_there_is_one():
    from seqnet.report.notes import notes_section

    assert notes_section(_results({"single": 0.5, "s1": 0.9})) == []
    (section,) = notes_section(_results({"single": 0.9, "s1<b>": 0.1, "s1": 0.5}))
    assert section.id == "notes" and "<li>s1 (R@1 0.500) is below the model-free single (0.900)" in section.body
    trivial = {**_results({"single": 0.5, "s1": 0.9}), "trivial_ks": "R@20 & R@100 are trivial here"}
    (section,) = notes_section(trivial)  # the default Ks' note after the table is in the shared report too
    assert "<li>R@20 &amp; R@100 are trivial here</li>" in section.body


def test_a_table_without_a_header_has_no_empty_first_row():
    from seqnet.report.markup import table_html

    for blank in (None, [], ["", ""]):
        out = table_html(blank, [("a", 1)])
        assert out.count("<tr>") == 1 and "<th>" not in out and "<thead>" not in out
    assert "<thead><tr><th>k</th><th>v</th></tr></thead>" in table_html(["k", "v"], [("a", 1)])


def test_an_hvpr_on_a_model_free_shortlist_names_its_shortlist():
    # Nordland64's benchmark: hvpr-single 0.441 below raw+seqmatch 0.460 (817 queries)
    res = _results({"raw+seqmatch": 0.460, "hvpr-single": 0.441}, queries=817)
    (note,) = learned_below_baseline(res)
    assert note.causes[0].startswith("its shortlist is the model-free single")


def test_a_pca_folded_into_the_models_is_not_called_missing():
    # the benchmark folds its PCA into the models: their in_dims are the raw D, but PCA was applied
    models = {"s1": {"in_dims": 7168, "out_dims": 256, "seq_len": 1, "w": 1}}
    res = _results({"single": 0.7, "s1": 0.4}, models=models)
    assert any("D = 7168 without PCA" in c for c in likely_causes("s1", res))
    res["config"]["benchmark"] = {"pca_dims": 64}
    assert not any("without PCA" in c for c in likely_causes("s1", res))


def test_a_gap_a_sign_test_cannot_tell_says_so_and_nothing_generic():
    from seqnet.report.guidance import within_chance

    assert [within_chance(k) for k in range(8)] == [True] * 6 + [False] * 2
    assert 2 * 0.5**5 > 0.05 > 2 * 0.5**6  # the sign test's two-sided p when all k differing queries go one way
    (small,) = learned_below_baseline(_results({"single": 0.32, "s1": 0.30}, queries=150))  # 3 queries apart
    assert small.causes == ("possibly chance: 3 of 150 queries apart (a sign test cannot tell fewer than 6 apart "
                            "from chance)",)
    (big,) = learned_below_baseline(_results({"single": 0.60, "s1": 0.30}, queries=150))
    assert not any("chance" in c for c in big.causes) and "training data" in big.causes[-1]


def test_the_shortlist_advice_names_only_what_did_better():
    res = _results({"raw+seqmatch": 0.80, "hvpr-single": 0.714, "hvpr": 0.619, "hvpr-fused": 0.571})
    note = next(n for n in learned_below_baseline(res) if n.learned == "hvpr-single")
    assert not any("hvpr-fused" in c or "better" in c for c in note.causes)
    res = _results({"raw+seqmatch": 0.80, "hvpr-single": 0.6, "hvpr": 0.7})
    note = next(n for n in learned_below_baseline(res) if n.learned == "hvpr-single")
    assert "(better here: hvpr)" in note.causes[0]
    note = learned_below_baseline(_results({"raw+seqmatch": 0.80, "hvpr-single": 0.6}))[0]
    assert "(a learned shortlist: hvpr, hvpr-fused)" in note.causes[0]


def test_notes_with_the_same_causes_are_one_line():
    notes = learned_below_baseline(_results({"single": 0.9, "s1": 0.3, "raw+seqmatch": 0.9, "s1+seqmatch": 0.4}))
    (line,) = format_notes(notes)
    assert line.startswith("note: s1 (R@1 0.300) is below the model-free single (0.900); s1+seqmatch (R@1 0.400)")
    assert line.count("likely:") == 1 and notes[0].to_dict()["text"] == notes[0].text()


def test_a_learned_method_alone_is_named_with_what_to_add():
    from seqnet.report.guidance import unmatched

    got = unmatched(_results({"seqnet": 0.5, "s1+seqmatch": 0.6, "s1": 0.2, "single": 0.1, "raw+seqmatch": 0.3,
                              "delta": 0.2}))
    assert got == []
    assert unmatched(_results({"seqnet": 0.5, "s1+seqmatch": 0.6, "s1": 0.2})) == [
        "seqnet (add smoothing or delta to see whether the model helps)",
        "s1+seqmatch (add raw+seqmatch to see whether the model helps)",
        "s1 (add single to see whether the model helps)"]
    assert unmatched(_results({"hvpr": 0.5, "s1+seqmatch": 0.6})) == [
        "hvpr and s1+seqmatch (add raw+seqmatch to see whether the models help)"]  # one counterpart: one line
    assert unmatched(_results({"seqnet": 0.268, "single": 0.4})) == [
        "seqnet (add smoothing or delta to see whether the model helps; it is already below the single-frame "
        "single: R@1 0.268 against 0.400)"]
    assert unmatched(_results({"seqnet": 0.5, "single": 0.4})) == [
        "seqnet (add smoothing or delta to see whether the model helps)"]


def test_the_html_results_table_marks_the_row():
    from types import SimpleNamespace

    from seqnet.report.html import results_section

    res = _results({"single": 0.9, "s1": 0.3})
    for r in res["methods"].values():
        r.update({f"recall@{k}": r["recall@1"] for k in (5, 10, 20)}, method={"kind": "knn"})
    res["config"]["ks"] = [1, 5]
    body = results_section(SimpleNamespace(results=res)).body
    s1_row = next(row for row in body.split("<tr>") if row.startswith("<td>s1</td>"))
    assert s1_row.split("</tr>")[0].endswith("<td>learned, below model-free single</td>")
    single_row = next(row for row in body.split("<tr>") if row.startswith("<td>single</td>"))
    assert single_row.split("</tr>")[0].endswith("<td></td>")


def test_the_summary_gives_the_range_of_query_counts():
    from types import SimpleNamespace

    import numpy as np

    from seqnet.report.html import ReportConfig, summary_section

    res = {"methods": {"single": {"queries": 25}, "raw+seqmatch": {"queries": 21}}, "config": {"dataset": "d"}}
    body = summary_section(SimpleNamespace(results=res, r_items=np.arange(3)), ReportConfig()).body
    assert "<td>queries evaluated</td><td>21–25 (by method: the results table&#x27;s column)</td>" in body
    res["methods"].pop("single")
    body = summary_section(SimpleNamespace(results=res, r_items=np.arange(3)), ReportConfig()).body
    assert "<td>queries evaluated</td><td>21</td>" in body


def test_a_specific_cause_that_does_not_explain_keeps_the_training_cause_beside_it():
    """An L mismatch (or D, or few queries) may add to the loss, not explain it: the training-data cause is said
    beside it (it was dropped, and following the --seq-len hint left the model as far below)."""
    models = {"seqnet": {"in_dims": 512, "out_dims": 512, "seq_len": 5, "w": 3}}
    causes = likely_causes("seqnet", _results({"seqnet": 0.2, "delta": 0.7}, models=models, seq_len=10))
    assert any("evaluated at L=10" in c for c in causes) and any("too little or too different" in c for c in causes)
    near = likely_causes("s1", _results({"s1": 0.69, "single": 0.70}), (0.69, 0.70))  # one query: chance explains
    assert near[0].startswith("possibly chance") and not any("too little" in c for c in near)


def test_an_hvpr_capped_by_its_shortlist_says_so():
    """An HVPR whose R@1 reaches what its shortlist of K holds (the entry's shortlist_recall) loses in the shortlist,
    not the re-ranking, learned shortlist or not: said, with --top-k; with room left, not said."""
    res = _results({"hvpr-s1": 0.786, "raw+seqmatch": 0.911}, queries=56)
    res["methods"]["hvpr-s1"]["shortlist_recall"] = {"k": 10, "recall": 0.786}
    (note,) = learned_below_baseline(res)
    assert note.causes[0].startswith("its shortlist (s1 top-10) holds a correct reference for only 0.786")
    assert "--top-k" in note.causes[0] and not any("too little" in c for c in note.causes)
    res["methods"]["hvpr-s1"]["shortlist_recall"]["recall"] = 0.95
    assert not any("its shortlist" in c for c in learned_below_baseline(res)[0].causes)


def test_a_shortlist_one_query_above_r_at_1_is_the_cap():
    """The 51a M4 case: hvpr 0.8488 with a shortlist recall of 0.8605 over 86 queries (exactly one query apart, as
    results.json rounds them) was blamed on the training data; --top-k 100 gave 0.988. Within one query the shortlist
    is the cap; two queries apart with the shortlist below the baseline, it is named beside the training cause."""
    res = _results({"hvpr": 0.8488, "raw+seqmatch": 0.9884}, queries=86)  # 73, 85 of 86
    res["methods"]["hvpr"]["shortlist_recall"] = {"k": 10, "recall": 0.8605}  # 74 of 86 (0.86047), rounded
    (note,) = learned_below_baseline(res)
    assert note.causes[0].startswith("its shortlist (seqnet top-10) holds a correct reference for only 0.861 of the "
                                     "queries, which caps its R@1") and "--top-k" in note.causes[0]
    assert not any("too little" in c for c in note.causes)
    res["methods"]["hvpr"]["recall@1"] = 0.8372  # the re-ranking loses 2 queries too: both said
    (note,) = learned_below_baseline(res)
    assert note.causes[0].endswith("below the model-free 0.988: no re-ranking of it reaches that; a larger --top-k "
                                   "(or a better shortlist)")
    assert any("too little" in c for c in note.causes)
    res["methods"]["hvpr"]["shortlist_recall"]["recall"] = 1.0  # room left above the baseline: not the shortlist
    assert not any("shortlist" in c for c in learned_below_baseline(res)[0].causes)


def test_without_r_at_1_the_smallest_k_is_compared():
    """--ks 5,10: the notes compare R@5 (they vanished without R@1) and say so."""
    methods = {"single": {"recall@5": 0.733, "recall@10": 0.767, "queries": 60},
               "s1": {"recall@5": 0.583, "recall@10": 0.650, "queries": 60}}
    (note,) = learned_below_baseline({"methods": methods, "config": {}})
    assert note.k == 5 and note.finding() == "s1 (R@5 0.583) is below the model-free single (0.733)"


def test_the_training_queries_a_checkpoint_records_are_named_in_the_training_cause(synth_dataset):
    """A model trained on 12 queries below its baseline got only the generic training-data cause; the count its
    checkpoint records (``trained_on["train_queries"]``) reaches ``results.json`` (``training_queries``, by
    :func:`model_entries` in eval) and the cause names it. A checkpoint that records none keeps the generic text."""
    import torch

    from seqnet.eval.config import EvalConfig
    from seqnet.eval.evaluate import evaluate
    from seqnet.report.guidance import model_entries
    from seqnet.sequence.model import SeqNet

    s1 = {"in_dims": 64, "out_dims": 64, "seq_len": 1, "w": 1}
    causes = likely_causes("s1", _results({"s1": 0.27, "single": 0.53}, 30, {"s1": {**s1, "training_queries": 12}}))
    assert any("D x out x w weights (S_1 learnt from 12 training queries), or a val split" in c for c in causes)
    both = {"seqnet": {**s1, "seq_len": 5, "training_queries": 180}, "s1": {**s1, "training_queries": 1}}
    causes = likely_causes("hvpr", _results({"hvpr": 0.2, "raw+seqmatch": 0.7}, models=both))
    assert any("(S_L learnt from 180 training queries, S_1 learnt from 1 training query)" in c for c in causes)
    plain = likely_causes("s1", _results({"s1": 0.27, "single": 0.53}, 30, {"s1": s1}))
    assert any(c.startswith("too little or too different training data for the model's D x out x w weights, or")
               for c in plain)

    torch.manual_seed(0)
    model = SeqNet(synth_dataset.query.dim, 8, 1, 1)
    assert model_entries({"s1": model}) == {"s1": model.config()}  # none recorded
    model.trained_on = {"dataset": "ds", "split": "train", "train_queries": [0, 12]}
    assert model_entries({"s1": model})["s1"] == {**model.config(), "training_queries": 12}
    res = evaluate(synth_dataset.split("test"), EvalConfig(methods=("single", "s1"), seq_len=1, device="cpu"),
                   {"s1": model}).results
    assert res["config"]["models"]["s1"]["training_queries"] == 12
    assert res["methods"]["s1"]["method"]["models"]["s1"]["training_queries"] == 12
    model.trained_on["trained_queries"] = 9  # the queries it trained on, since 2026-12-05
    assert model_entries({"s1": model})["s1"]["training_queries"] == 9


def test_the_training_queries_named_are_those_trained_on_not_the_split(tmp_path, caplog):
    """The notes said "S_L learnt from 60 training queries" (the train range's length) of a run whose training
    logged "on 56 queries" (4 without a full window): the checkpoint records the count trained on, and the notes
    name it."""
    import logging
    import re

    from seqnet.data.io import save_dataset
    from seqnet.data.synth import make_synthetic
    from seqnet.report.guidance import model_entries
    from seqnet.sequence.checkpoints import load_model
    from seqnet.train.config import TrainConfig
    from seqnet.train.loop import main

    data = save_dataset(make_synthetic(places=200, dim=8), tmp_path / "ds")
    conf = TrainConfig(optimizer="adam", lr=1e-2, batch_size=16, cache_refresh=40, n_neg_sample=50, seq_len=5, w=3,
                       out_dims=8, device="cpu", epochs=1)
    with caplog.at_level(logging.INFO, logger="seqnet"):
        run = main(conf, data, tmp_path / "run")
    logged = int(re.search(r"training S_5 .* on (\d+) queries", caplog.text).group(1))
    model = load_model(run / "best.pt")
    a, b = model.trained_on["train_queries"]
    assert logged < b - a  # the range's ends have no full window
    assert model.trained_on["trained_queries"] == logged
    assert model_entries({"seqnet": model})["seqnet"]["training_queries"] == logged


def _reduced(learned: float, reduced: float, unreduced: float, queries: int = 86) -> dict:
    """s1+seqmatch and raw+seqmatch on a --pca dataset, raw+seqmatch's recall on the unreduced one recorded."""
    res = _results({"raw+seqmatch": reduced, "s1+seqmatch": learned}, queries=queries)
    res["methods"]["raw+seqmatch"]["unreduced"] = {"dataset": "/w/ds_32x16", "dims": [512, 256],
                                                   "recall@1": unreduced, "queries": queries}
    return res


def test_a_learned_method_below_the_unreduced_counterpart_is_noted_with_the_pcas_cost():
    """The 51a M2 case: after --pca 256, s1+seqmatch 0.930 beat the reduced raw+seqmatch 0.837 and went unmarked,
    while the unreduced raw+seqmatch gave 0.953: the note names that baseline and the PCA's cost (no training
    cause: the model gains on what it was given). Below both: the training cause too. Above the unreduced one, or
    without the record: as before."""
    (note,) = learned_below_baseline(_reduced(0.930, 0.837, 0.953))
    assert (note.baseline, note.baseline_r1) == ("raw+seqmatch on the unreduced ds_32x16", 0.953)
    assert note.causes[0].startswith("the PCA (512 -> 256 dims) alone cost raw+seqmatch R@1 0.953 -> 0.837 on these "
                                     "queries (ds_32x16 holds the unreduced descriptors); hint: compare with a model "
                                     "trained on ds_32x16 itself")
    assert not any("too little" in c for c in note.causes)
    assert format_notes([note])[0].startswith("note: s1+seqmatch (R@1 0.930) is below the model-free raw+seqmatch on "
                                              "the unreduced ds_32x16 (0.953) on the same queries; likely: the PCA")
    assert row_marks([note]) == {"s1+seqmatch": "learned, below model-free raw+seqmatch on the unreduced ds_32x16"}
    (both,) = learned_below_baseline(_reduced(0.700, 0.837, 0.953))
    assert both.causes[0].startswith("the PCA") and any("too little" in c for c in both.causes)
    assert learned_below_baseline(_reduced(0.960, 0.837, 0.953)) == []
    assert learned_below_baseline(_reduced(0.930, 0.837, 0.9302)) == []  # within a query of the unreduced one
    (plain,) = learned_below_baseline(_reduced(0.800, 0.837, 0.700))  # the PCA helped: the usual note
    assert plain.baseline == "raw+seqmatch" and not plain.causes[0].startswith("the PCA")
    other = _reduced(0.930, 0.837, 0.953)
    other["methods"]["raw+seqmatch"]["unreduced"]["queries"] = 90  # not the same queries: not compared
    assert learned_below_baseline(other) == []


def test_a_checkpoint_from_the_first_epoch_is_named_as_barely_trained(tmp_path):
    """The 51a L3 case: best.pt from epoch 1 of 40 (SGD at lr 1e-4, loss 0.3098 then) was blamed on the training
    data only; what the checkpoint and the last.pt beside it record names it. A later epoch says nothing."""
    import torch

    from seqnet.report.guidance import barely_trained, training_record

    state = {"conv.weight": torch.zeros(4, 4, 1), "conv.bias": torch.zeros(4)}
    base = {"format": "seqnet-checkpoint/1", "model": {"in_dims": 4, "out_dims": 4, "seq_len": 1, "w": 1},
            "state_dict": state, "best_epoch": 1, "config": {"epochs": 40}, "dataset_path": "/d"}
    history = [{"epoch": e, "loss": 0.3098 - 0.0019 * (e - 1)} for e in range(1, 41)]
    torch.save({**base, "epoch": 1}, tmp_path / "best.pt")
    torch.save({**base, "epoch": 40, "train_state": {"history": history}}, tmp_path / "last.pt")
    record = training_record(str(tmp_path / "best.pt"))
    assert record is not None and (record["epoch"], record["epochs"], record["last_epoch"]) == (1, 40, 40)
    said = barely_trained({"seqnet": {"training": record}})
    assert said == ("S_L's checkpoint is from epoch 1 of 40 (val R@1 never rose after it, training loss 0.3098 at "
                    "epoch 1, 0.2357 at 40): the model is barely trained; hint: a larger --lr or --optimizer adam, "
                    "and a val split large enough to choose the epoch")
    models = {"seqnet": {"in_dims": 4, "out_dims": 4, "seq_len": 5, "w": 3, "training": record}}
    (note,) = learned_below_baseline(_results({"seqnet": 0.488, "delta": 0.698}, queries=86, models=models))
    assert any(c.startswith("S_L's checkpoint is from epoch 1 of 40") for c in note.causes)
    assert barely_trained({"seqnet": {"training": {**record, "epoch": 12}}}) is None
    assert barely_trained({"s1": {"training": {"epoch": 1, "epochs": 1}}}) is None  # --epochs 1: nothing else ran
    assert barely_trained({"s1": {"training": {"epoch": 1, "epochs": 40}}}).startswith(
        "S_1's checkpoint is from epoch 1 of 40 planned (val R@1 never rose after it)")
    adam = {**record, "optimizer": "adam", "lr": 0.001}  # hostile 52 own-data M2: Adam was offered to an Adam run
    assert barely_trained({"seqnet": {"training": adam}}).endswith(
        "barely trained; hint: a larger --lr (it was 0.001), and a val split large enough to choose the epoch")
    fit = {**adam, "loss": {1: 0.2993, 2: 0.1, 3: 0.0322}, "last_epoch": 3, "epochs": 3}  # the loss fell 9x
    said = barely_trained({"seqnet": {"training": fit}})
    assert "fit its training queries but did not generalise" in said and "barely" not in said, said
    assert "--optimizer" not in said and "training loss 0.2993 at epoch 1, 0.0322 at 3" in said, said


def test_the_few_queries_cause_names_the_recall_compared():
    """Own-data hostile 52 L7: with --ks 5,20 the note compared R@5 and said 'one query is 0.05 of R@1'."""
    res = {"methods": {n: {"recall@5": v, "recall@20": 0.9, "queries": 20, "method": {"seq_len": 5, "models": {}}}
                       for n, v in {"single": 0.60, "s1": 0.30}.items()}, "config": {"seq_len": 5, "models": {}}}
    (note,) = learned_below_baseline(res)
    assert note.k == 5 and "only 20 evaluated queries (one query is 0.05 of R@5)" in note.causes, note.causes


def test_a_model_trained_on_another_dataset_is_named_as_a_cause(tmp_path):
    """A checkpoint trained on dataset A evaluated on dataset B (same D) below its baseline got only the generic
    training-data cause; the checkpoint records its dataset, so the cause names it. On A itself it is not said."""
    from seqnet.data.io import load_dataset, save_dataset
    from seqnet.data.synth import make_synthetic
    from seqnet.eval.config import EvalConfig
    from seqnet.eval.evaluate import evaluate
    from seqnet.sequence.checkpoints import load_model
    from seqnet.train.config import TrainConfig
    from seqnet.train.loop import main

    def bare(seed: int):  # descriptors of unknown making (a user's .npy files): no provenance to tell them apart
        ds = make_synthetic(places=200, dim=8, seed=seed)
        ds.reference.provenance = ds.query.provenance = None
        return ds

    a, b = (save_dataset(bare(seed), tmp_path / name) for seed, name in ((0, "a"), (1, "b")))
    conf = TrainConfig(optimizer="adam", lr=1e-2, batch_size=16, cache_refresh=40, n_neg_sample=50, seq_len=1, w=1,
                       out_dims=8, device="cpu", epochs=1)
    model = load_model(main(conf, a, tmp_path / "run") / "best.pt")
    ev_conf = EvalConfig(methods=("single", "s1"), seq_len=1, device="cpu", split="test")
    on_b = evaluate(load_dataset(b), ev_conf, {"s1": model}).results
    assert on_b["config"]["models"]["s1"]["trained_on_dataset"] == str(a.resolve())
    causes = likely_causes("s1", on_b, explained=True)
    assert causes[0] == (f"S_1 was trained on another dataset ({a.resolve()}): a model learns the descriptors and "
                         "places it trained on, and another describer's descriptors of the same D fit it in shape "
                         "only (hint: train on this dataset's train split: seqnet train --dataset THIS)")
    on_a = evaluate(load_dataset(a), ev_conf, {"s1": model}).results
    assert "trained_on_dataset" not in on_a["config"]["models"]["s1"]
    assert not any("another dataset" in c for c in likely_causes("s1", on_a))


def test_a_narrow_layer_is_named_first_and_never_told_to_narrow(tmp_path):
    """S_1 with --out-dims 16 on 256-D descriptors (s1 R@1 0.050 against single 0.433; 0.467 without it) got
    'barely trained: --optimizer adam' (0.067 when followed) and then 'fewer weights (a smaller --out-dims)': the
    narrow layer is named, and no hint narrows it further."""
    s1 = {"in_dims": 256, "out_dims": 16, "seq_len": 1, "w": 1}
    fit = {"epoch": 1, "epochs": 6, "last_epoch": 6, "optimizer": "adam", "lr": 0.01,
           "loss": {1: 0.3, 6: 0.05}}  # loss fell: fit to training queries
    causes = likely_causes("s1", _results({"s1": 0.05, "single": 0.433}, 60, {"s1": {**s1, "training": fit}}))
    assert causes[0] == ("S_1 maps 256-D descriptors to 16-D (--out-dims): a layer this narrow loses much of what "
                         "tells places apart; hint: train without --out-dims (out = D), or with a larger one; to save "
                         "memory, reduce D with a PCA measured on val instead (seqnet train says what it costs)")
    assert not any("smaller --out-dims" in c for c in causes)
    assert any("did not generalise" in c for c in causes)
    for out in (256, 128):  # out = D, or half of it: not narrow (64, a quarter, scored 0.217: narrow)
        wide = likely_causes("s1", _results({"s1": 0.05, "single": 0.433}, 60, {"s1": {**s1, "out_dims": out,
                                                                                       "training": fit}}))
        assert not any("narrow" in c for c in wide) and any("smaller --out-dims" in c for c in wide)
    both = {"seqnet": {**s1, "seq_len": 5, "w": 5, "out_dims": 8}, "s1": {**s1, "out_dims": 31, "in_dims": 64}}
    assert likely_causes("hvpr", _results({"hvpr": 0.2, "raw+seqmatch": 0.7}, models=both))[0].startswith(
        "S_L maps 256-D descriptors to 8-D and S_1 maps 64-D descriptors to 31-D (--out-dims)")


def test_a_shortlist_that_reaches_the_baseline_is_not_the_cap():
    """Session 54 on 300 Nordland64 frames: hvpr 0.964 (54 of 56) with a seqnet top-20 shortlist holding 0.982 (55),
    against raw+seqmatch 0.982. The shortlist reaches the baseline, so the query lost to it is the re-ranking's: the
    note said 'which caps its R@1: the re-ranking is not what loses', which is false there."""
    res = _results({"hvpr": 54 / 56, "raw+seqmatch": 55 / 56}, queries=56)
    res["methods"]["hvpr"]["shortlist_recall"] = {"k": 20, "recall": 55 / 56}
    (note,) = learned_below_baseline(res)
    assert note.causes[0].startswith("possibly chance: 1 of 56 queries apart")
    assert not any("shortlist" in c for c in note.causes), note.causes
    res["methods"]["raw+seqmatch"]["recall@1"] = 56 / 56  # the shortlist one query short of the baseline: the cap
    (note,) = learned_below_baseline(res)
    assert any("which caps its R@1" in c for c in note.causes)
