"""``seqnet experiment comparison`` (the paper's Table I, "Performance Comparison", and its Recall@K
curves, Fig. 3): every method of the paper's table — single-image, sequential descriptors, sequence
score aggregation, hierarchical — on the benchmark's val and test splits, R@1/5/20 beside the paper's
Oxford-FD and Brisbane columns, and a Recall@K plot of the test split.

The paper's three single-image rows (AP-GeM, DenseVLAD, NetVLAD) are one row here: the benchmark's
raw descriptor (``single``; NetVLAD is the paper's input descriptor, as the raw descriptor is ours).
Delta is the paper's (``delta-paper``), GISM / GRH are the ``graph`` / ``grh`` / ``grh-dh`` matchers
(docs/matchers.md says how they differ from the published algorithms). ``extra_methods`` (default
``hvpr-fused``) are seqnet's own rows, printed after the paper's.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

from ...core.config import Config
from ...eval.evaluation import Evaluation
from ...methods.grammar import parse_method
from ...report.paper import TABLE_I, PaperRow, PaperTable, methods_of, recall_lookup, side_by_side
from ...report.tables import method_colours, new_figure
from ..nordland64 import Nordland64Config
from .common import (
    Outputs,
    check_experiment,
    evaluate_splits,
    locked_dirs,
    queries_of,
    source,
    summary,
    table_section,
    truth_text,
    write_outputs,
)


@dataclasses.dataclass(frozen=True)
class ComparisonConfig(Config):
    """Settings of the comparison: the benchmark's (data, models, L) and seqnet's rows added to the paper's."""

    benchmark: Nordland64Config = Nordland64Config()
    extra_methods: tuple[str, ...] = ("hvpr-fused",)

    def __post_init__(self) -> None:
        self._set("extra_methods", tuple(parse_method(m).name for m in self.extra_methods))

    def table(self) -> PaperTable:
        """Table I with a row per extra method (no paper value)."""
        extra = tuple(PaperRow(f"seqnet: {m}", ("-",) * len(TABLE_I.columns), m) for m in self.extra_methods
                      if m not in methods_of(TABLE_I))
        return dataclasses.replace(TABLE_I, rows=(*TABLE_I.rows, *extra))


def main(conf: ComparisonConfig, data: str | Path | None, out: str | Path, cache: str | Path | None = None,
         dataset: str | Path | None = None, models: Sequence[str | Path] = (), overwrite: bool = False) -> Path:
    """Run the comparison on the nordland64 folder ``data`` (or a seqnet ``dataset`` with its ``models``); writes
    ``results.json``, ``results.md``, ``comparison.png`` (Recall@K of the test split), ``report.html`` (the test
    evaluation) and ``config.json`` to ``out``."""
    out = Path(out)
    cache = Path(cache) if cache else out
    table = conf.table()
    with locked_dirs(out, cache):
        check_experiment(out, "comparison", overwrite)
        p = source(conf.benchmark, data, cache, dataset, models, overwrite)
        methods = p.runnable(methods_of(table))  # rows without their models show "–"
        evs = evaluate_splits(p, conf.benchmark.eval_config().merge(methods=methods))
        values = [evs[s].results["methods"] for s in p.splits]
        denominator = conf.benchmark.recall_denominator
        md = (f"# Performance comparison (paper: Table I), {p.name}\n\n"
              f"L = {conf.benchmark.seq_len}, {truth_text(evs[p.main])}, shortlist K = {conf.benchmark.top_k}; "
              "queries: " + ", ".join(f"{s} {queries_of(evs[s])}" for s in p.splits) + ".\n\n"
              + side_by_side(table, tuple(f"{p.name} {s}" for s in p.splits), recall_lookup(values), denominator)
              + own_data_command(methods, conf.benchmark.seq_len))
        results = {"experiment": "comparison", "paper_table": table.key, "methods": list(methods),
                   "recall_denominator": denominator, "details": {s: summary(e) for s, e in evs.items()},
                   "timings_s": p.seconds, "provenance": p.ds.reference.provenance}
        header = ["method", *(f"R@{k} {p.main}" for k in conf.benchmark.ks)]
        rows = [[m, *(values[-1][m][f"recall@{k}"] for k in conf.benchmark.ks)] for m in methods]
        o = Outputs("comparison", results, md, recall_figure(evs[p.main], methods, conf.benchmark.ks, p.name),
                    [table_section("experiment", "Performance comparison (Table I)",
                                   {f"Recall@K, {p.main}": (header, rows)},
                                   f"The paper's Table I methods on the {p.name} {p.main} split.")],
                    (evs[p.main], p.ds.split(p.main)), evs)
        return write_outputs(o, conf, dataset or data, out,
                             f"Experiment: performance comparison (paper Table I), {p.main}", overwrite)


def own_data_command(methods: tuple[str, ...], seq_len: int) -> str:
    """The command that gives the "ours" column of these rows on any seqnet dataset."""
    return ("\nThe same rows on your own dataset (any `seqnet dataset` directory and its S_L / S_1 models):\n\n"
            f"    seqnet eval --dataset DIR --model S_L.pt --model S_1.pt --seq-len {seq_len} --ks 1,5,20 \\\n"
            f"        --method {','.join(methods)}\n")


def recall_figure(ev: Evaluation, methods: tuple[str, ...], ks: tuple[int, ...], name: str = "Nordland64") -> object:
    """Recall@K against K, one line per method (the paper's Fig. 3 for one dataset)."""
    fig, ax = new_figure(8.5, 4.8)
    res = ev.results["methods"]
    for m, colour in zip(methods, method_colours(len(methods)), strict=True):
        style = "-" if parse_method(m).kind == "hvpr" else "--" if parse_method(m).kind == "match" else ":"
        ax.plot(ks, [res[m][f"recall@{k}"] for k in ks], style, marker="o", ms=3, color=colour, label=m)
    ax.set_xscale("log")
    ax.set_xticks(list(ks), [str(k) for k in ks])
    ax.set_xlabel("K")
    ax.set_ylabel("Recall@K (test)")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.0, 0.5))
    ax.set_title(f"Recall@K, {name} (solid: hierarchical, dashed: score aggregation, dotted: descriptors)")
    return fig

