"""``seqnet experiment longer-sequences``: HVPR with the S_L shortlist (L = the benchmark's, 5) and
longer re-ranking sequences L_m (5, 10, 20 by default), beside whole-map S_1 + SeqMatch and the
graph matcher at the same L_m.

The S_L model and its windows stay L frames long; only the sequence matchers (SeqMatch, graph)
use L_m frames (``EvalConfig.match_len``). Queries are the places whose L_m window fits in
the split, so the longest L_m evaluates a few fewer queries (counted in the results).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ...core.config import Config, check_ints
from ...eval.evaluation import Evaluation
from ...methods.grammar import parse_method
from ...report.paper import TABLE_S2, recall_lookup, side_by_side
from ...report.tables import method_colours, new_figure
from ..nordland64 import Nordland64Config
from .common import (
    Outputs,
    check_experiment,
    evaluate_splits,
    locked_dirs,
    markdown_table,
    queries_of,
    recall_at_1,
    recall_table,
    source,
    summary,
    table_section,
    write_outputs,
)

METHODS = ("seqnet", "s1+seqmatch", "hvpr", "hvpr-fused", "s1+graph", "hvpr-seqnet:s1+graph")


@dataclasses.dataclass(frozen=True)
class LongerConfig(Config):
    """Settings of the longer-sequences experiment: the benchmark's, the lengths L_m and the methods."""

    benchmark: Nordland64Config = Nordland64Config()
    lengths: tuple[int, ...] = (5, 10, 20)
    methods: tuple[str, ...] = METHODS

    def __post_init__(self) -> None:
        self._set("lengths", check_ints("lengths", self.lengths, 1))
        self._set("methods", tuple(parse_method(m).name for m in self.methods))


def main(conf: LongerConfig, data: str | Path | None, out: str | Path, cache: str | Path | None = None,
         dataset: str | Path | None = None, models: Sequence[str | Path] = (), overwrite: bool = False) -> Path:
    """Run the experiment on the nordland64 folder ``data`` (or a seqnet ``dataset`` with its ``models``); writes
    ``results.json``, ``results.md``, ``longer_sequences.png``, ``report.html`` (the longest L_m on test) and
    ``config.json`` to ``out``."""
    out = Path(out)
    cache = Path(cache) if cache else out
    with locked_dirs(out, cache):
        check_experiment(out, "longer_sequences", overwrite)
        p = source(conf.benchmark, data, cache, dataset, models, overwrite)
        methods = p.runnable(conf.methods)
        evs: dict[str, Evaluation] = {}
        for lm in conf.lengths:
            ec = conf.benchmark.eval_config().merge(methods=methods, match_len=lm)
            for split, ev in evaluate_splits(p, ec).items():
                evs[f"{split} L_m={lm}"] = ev
        header = ["method", *(f"R@1 {k}" for k in evs)]
        rows = recall_table(evs, methods)
        queries = {k: queries_of(e) for k, e in evs.items()}
        results = {"experiment": "longer-sequences", "lengths": list(conf.lengths), "methods": list(methods),
                   "recall@1": recall_at_1(evs, methods),
                   "queries": queries, "details": {k: summary(e) for k, e in evs.items()}, "timings_s": p.seconds,
                   "provenance": p.ds.reference.provenance}
        md = (f"# Longer sequences (S_L with L={conf.benchmark.seq_len}, re-ranking length L_m), {p.name}\n\nRecall@1; "
              "queries per column: " + ", ".join(f"{k} {v}" for k, v in queries.items()) + ".\n\n"
              + markdown_table(header, rows) + f"\nThe paper's table ({p.main} split):\n\n"
              + side_by_side(TABLE_S2, tuple(f"L_m={lm}" for lm in conf.lengths),
                             recall_lookup([evs[f"{p.main} L_m={lm}"].results["methods"] for lm in conf.lengths]),
                             conf.benchmark.recall_denominator))
        last = conf.lengths[-1]
        o = Outputs("longer_sequences", results, md, longer_figure(rows, list(evs), conf.lengths),
                    [table_section("experiment", "Longer sequences", {"Recall@1": (header, rows)},
                                   f"S_L (L={conf.benchmark.seq_len}) shortlist; sequence matchers over L_m frames.")],
                    (evs[f"{p.main} L_m={last}"], p.ds.split(p.main)), evs)
        return write_outputs(o, conf, dataset or data, out, f"Experiment: longer sequences ({p.main}, L_m={last})",
                             overwrite)


def longer_figure(rows: list[list], columns: list[str], lengths: tuple[int, ...]) -> object:
    """R@1 against L_m, one line per method: test solid, val dashed."""
    fig, ax = new_figure(8.5, 4.5)
    low = min((v for r in rows for v in r[1:] if v is not None), default=0.0)
    for row, colour in zip(rows, method_colours(len(rows)), strict=True):
        for split, style in (("test", "-"), ("val", "--"), ("all", "-")):
            if f"{split} L_m={lengths[0]}" not in columns:  # a user's dataset: its own splits
                continue
            ys = [row[1 + columns.index(f"{split} L_m={lm}")] for lm in lengths]
            ax.plot(lengths, [np.nan if y is None else y for y in ys], style, marker="o", color=colour,
                    label=f"{row[0]} ({split})")
    ax.set_xticks(list(lengths))
    ax.set_xlabel("L_m (frames matched by SeqMatch / graph)")
    ax.set_ylabel("Recall@1")
    ax.set_ylim(max(0.0, low - 0.05), 1.01)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.0, 0.5))
    ax.set_title("Longer re-ranking sequences")
    return fig
