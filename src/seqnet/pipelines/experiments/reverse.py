"""``seqnet experiment reverse`` (the paper's Table III, "Reverse Traverse"): the reference traversed in
the opposite direction to the query.

The reference of each split is put in reverse order (positions and image names follow, so the
ground truth is unchanged), the query is not. SeqMatch assumes both go the same way; its reverse
variant (matcher ``seqmatch-rev``) walks the reference backwards. S_L is used as trained on
forward sequences (not retrained on reversed ones): its reference windows are now the reversed
frame order it never saw. Every method is evaluated on the normal and the reversed reference.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ...core.config import Config
from ...data.traverse import Dataset, Traverse
from ...methods.grammar import parse_method
from ...report.paper import TABLE_III, recall_lookup, side_by_side
from ...report.tables import method_colours, new_figure
from ..nordland64 import Nordland64Config
from .common import (
    Outputs,
    check_experiment,
    evaluate_splits,
    locked_dirs,
    markdown_table,
    recall_at_1,
    recall_table,
    source,
    summary,
    table_section,
    truth_text,
    write_outputs,
)

METHODS = ("single", "s1", "smoothing", "delta-paper", "raw+seqmatch", "raw+seqmatch-rev", "s1+seqmatch",
           "s1+seqmatch-rev", "seqnet", "hvpr",
           "hvpr-seqnet:s1+seqmatch-rev", "hvpr-fused", "hvpr-fused:s1+seqmatch-rev")


@dataclasses.dataclass(frozen=True)
class ReverseConfig(Config):
    """Settings of the reverse experiment: the benchmark's (data, models) and the methods compared."""

    benchmark: Nordland64Config = Nordland64Config()
    methods: tuple[str, ...] = METHODS

    def __post_init__(self) -> None:
        self._set("methods", tuple(parse_method(m).name for m in self.methods))


def reverse_reference(ds: Dataset) -> Dataset:
    """``ds`` with its reference traverse in reverse order (positions, names, sequence bounds and
    explicit positives follow, so what is correct does not change)."""
    r, n = ds.reference, len(ds.reference)
    bounds = None if r.seq_bounds is None else n - r.seq_bounds[::-1, ::-1]
    ref = Traverse(np.ascontiguousarray(r.descriptors[::-1]), r.positions[::-1].copy(),
                   names=None if r.names is None else r.names[::-1], seq_bounds=bounds,
                   name=f"{r.name} (reversed)", provenance=r.provenance)
    positives = None if ds.positives is None else ds.positives.select(np.arange(len(ds.query)), np.arange(n)[::-1])
    return dataclasses.replace(ds, reference=ref, positives=positives, name=f"{ds.name} reference reversed")


def main(conf: ReverseConfig, data: str | Path | None, out: str | Path, cache: str | Path | None = None,
         dataset: str | Path | None = None, models: Sequence[str | Path] = (), overwrite: bool = False) -> Path:
    """Run the experiment on the nordland64 folder ``data`` (or a seqnet ``dataset`` with its ``models``); writes
    ``results.json``, ``results.md``, ``reverse.png``, ``report.html`` and ``config.json`` to ``out``
    (descriptors and models cached in ``cache``, default ``out``)."""
    out = Path(out)
    cache = Path(cache) if cache else out
    with locked_dirs(out, cache):
        check_experiment(out, "reverse", overwrite)
        p = source(conf.benchmark, data, cache, dataset, models, overwrite)
        methods = p.runnable(conf.methods)
        ec = conf.benchmark.eval_config().merge(methods=methods)
        fwd, rev = evaluate_splits(p, ec), evaluate_splits(p, ec, transform=reverse_reference)
        evs = {f"{s} {d}": e[s] for s in p.splits for d, e in (("forward", fwd), ("reversed", rev))}
        header = ["method", *(f"R@1 {k}" for k in evs)]
        rows = recall_table(evs, methods)
        results = {"experiment": "reverse", "methods": list(methods), "recall@1": recall_at_1(evs, methods),
                   "details": {k: summary(e) for k, e in evs.items()}, "timings_s": p.seconds,
                   "provenance": p.ds.reference.provenance}
        rev_main = rev[p.main].results["methods"]
        md = (f"# Reverse traverse (reference in reverse order), {p.name}\n\nRecall@1; S_L as trained on forward "
              f"sequences; {truth_text(fwd[p.main])}.\n\n" + markdown_table(header, rows) + "\nThe paper's table "
              f"(both columns on the reversed reference, {p.main} split):\n\n"
              + side_by_side(TABLE_III, ("vanilla", "reverse"), recall_lookup([rev_main, rev_main]),
                             conf.benchmark.recall_denominator))
        o = Outputs("reverse", results, md, reverse_figure(rows, list(evs)),
                    [table_section("experiment", "Reverse traverse", {"Recall@1": (header, rows)},
                                   "The reference is traversed in reverse order; S_L is used as trained.")],
                    (rev[p.main], reverse_reference(p.ds.split(p.main))), evs)
        return write_outputs(o, conf, dataset or data, out,
                             f"Experiment: reverse traverse ({p.main}, reference reversed)", overwrite)


def reverse_figure(rows: list[list], columns: list[str]) -> object:
    """Grouped bars: R@1 of every method on the normal and the reversed reference."""
    fig, ax = new_figure(9, 4.5)
    width = 0.8 / len(columns)
    x = np.arange(len(rows))
    for i, (col, colour) in enumerate(zip(columns, method_colours(len(columns)), strict=True)):
        ax.bar(x + (i - (len(columns) - 1) / 2) * width, [r[i + 1] or 0.0 for r in rows], width, label=col,
               color=colour)
    ax.set_xticks(x, [r[0] for r in rows], rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("Recall@1")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=8)
    ax.set_title("Reverse traverse: normal vs reversed reference")
    return fig
