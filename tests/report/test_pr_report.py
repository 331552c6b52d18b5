"""Precision–recall in reports: curve points in results, AUC / R@100P columns, pr_curve.png."""

from __future__ import annotations

import json

import numpy as np

from seqnet.cli import main as cli_main
from seqnet.metrics.precision_recall import curve_points, precision_recall
from seqnet.report.tables import format_markdown, format_table, plot_pr_curves


def test_curve_points_keep_ends_and_bound_size(rng):
    conf, correct = rng.random(1000), rng.random(1000) < 0.7
    p, r, _ = precision_recall(conf, correct, np.ones(1000, bool))
    pts = curve_points(p, r, max_points=50)
    assert len(pts["recall"]) == 50 and pts["recall"][-1] == round(float(r[-1]), 4)
    assert pts["precision"][0] == round(float(p[0]), 4) and np.all(np.diff(pts["recall"]) >= 0)
    assert curve_points(p[:3], r[:3]) == {"precision": [round(float(x), 4) for x in p[:3]],
                                          "recall": [round(float(x), 4) for x in r[:3]]}
    assert curve_points(np.zeros(0), np.zeros(0)) == {"precision": [], "recall": []}


def test_markdown_has_pr_columns_and_text_table_does_not():
    methods = {"a": {"recall@1": 0.5, "auc": 0.61, "recall@100p": 0.2, "queries": 10, "timing_ms": {"total": 1.0}},
               "b": {"recall@1": 0.4, "queries": 10}}
    md = format_markdown(methods, ks=(1,))
    assert md.splitlines()[0] == "| method (R@K ÷ positives) | R@1 | AUC | R@100P | queries | total ms | ms/query |"
    assert "| a | 0.500 | 0.610 | 0.200 | 10 |" in md and "| b | 0.400 |   n/a |   n/a |" in md
    assert "AUC" not in format_table(methods, ks=(1,))


def test_plot_and_eval_out(synth_dir, tmp_path):
    out = tmp_path / "ev"
    assert cli_main(["eval", "--dataset", str(synth_dir), "--method", "single,raw+seqmatch", "--out", str(out),
                     "--device", "cpu"]) == 0
    res = json.loads((out / "results.json").read_text())
    curve = res["methods"]["raw+seqmatch"]["pr_curve"]
    assert len(curve["precision"]) == len(curve["recall"]) > 1
    assert (out / "pr_curve.png").stat().st_size > 1000
    path = plot_pr_curves({"x": {"pr_curve": curve, "auc": 0.5}, "no curve": {}}, tmp_path / "p.png", title="t")
    assert path.stat().st_size > 1000
