"""``seqnet experiment descriptors`` (the paper's supplementary table "Different Single Image Descriptor",
S3): the whole pipeline — describe, PCA, train S_L and S_1, evaluate every method — on different
single-image descriptors of the same frames.

``pixels`` is the benchmark's descriptor (its descriptors and models are the benchmark's);
``netvlad`` (clusters fitted by k-means on the train images' EfficientNet-Lite0 block-10
features), ``gmp`` and ``gem`` (global max / generalised-mean pooling of its head) run the CNN on
the 64×32 frames resized to ``cnn_size`` (default 128×64, chosen to keep each descriptor within
about ten minutes on two CPU cores). Everything fitted is fitted on the train range only.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ...core.config import Config, check_choice
from ...core.errors import ConfigError
from ...data.traverse import Dataset
from ...describe import DescribeConfig
from ...describe.config import check_size
from ...eval.evaluation import Evaluation
from ...methods.grammar import parse_method
from ...report.html import write_html_report
from ...report.paper import TABLE_S3, recall_lookup, side_by_side
from ...report.tables import method_colours, new_figure
from ..nordland64 import Nordland64Config
from ..nordland64.run import report_config
from .common import (
    Outputs,
    check_cache,
    check_experiment,
    evaluate_splits,
    locked_dirs,
    markdown_table,
    prepare,
    recall_at_1,
    recall_table,
    summary,
    table_section,
    write_outputs,
)

DESCRIPTORS = ("pixels", "netvlad", "gmp", "gem")  # "pixels": the benchmark's own descriptor settings
CNN_SIZE = (128, 64)


def describe_config(name: str, cnn_size: tuple[int, int] = CNN_SIZE) -> DescribeConfig:
    """The settings of descriptor ``name`` (a key of :data:`DESCRIPTORS`): the benchmark's pixels, or a
    CNN method on the frames resized to ``cnn_size`` (W, H)."""
    if check_choice("descriptor", name, DESCRIPTORS) == "pixels":
        return Nordland64Config().describe
    return DescribeConfig(method=name, size=cnn_size, batch_size=32)


@dataclasses.dataclass(frozen=True)
class DescriptorsConfig(Config):
    """Settings of the descriptors experiment: the benchmark's, the descriptors compared, the CNN input
    size (W, H) and extra methods (``delta-paper``: the paper's Delta, the original code's weighting) added
    to the benchmark's."""

    benchmark: Nordland64Config = Nordland64Config()
    descriptors: tuple[str, ...] = ("pixels", "netvlad", "gmp")
    cnn_size: tuple[int, int] = CNN_SIZE
    extra_methods: tuple[str, ...] = ("delta-paper",)

    def __post_init__(self) -> None:
        self._set("descriptors", tuple(dict.fromkeys(check_choice("descriptor", d, DESCRIPTORS)
                                                     for d in self.descriptors)))
        size = check_size(self.cnn_size if isinstance(self.cnn_size, str) else tuple(self.cnn_size))
        if isinstance(size, str):
            raise ConfigError(f"cnn_size must be W x H (e.g. 128x64), got {self.cnn_size!r}")
        self._set("cnn_size", size)
        self._set("extra_methods", tuple(parse_method(m).name for m in self.extra_methods))

    def describe(self, name: str) -> DescribeConfig:
        """The describe settings of descriptor ``name``."""
        return self.benchmark.describe if name == "pixels" else describe_config(name, self.cnn_size)

    @property
    def methods(self) -> tuple[str, ...]:
        """The benchmark's methods and the extra ones."""
        return tuple(dict.fromkeys((*self.benchmark.methods, *self.extra_methods)))


def main(conf: DescriptorsConfig, data: str | Path, out: str | Path, cache: str | Path | None = None,
         overwrite: bool = False) -> Path:
    """Run the experiment; writes ``results.json``, ``results.md``, ``descriptors.png``, ``report.html``
    (the first descriptor's test evaluation), ``NAME/report.html`` per descriptor and ``config.json``."""
    out = Path(out)
    cache = Path(cache) if cache else out
    with locked_dirs(out, cache):
        check_experiment(out, "descriptors", overwrite, conf.descriptors)
        benches = {name: conf.benchmark.merge(describe=conf.describe(name), methods=conf.methods)
                   for name in conf.descriptors}
        for bench in benches.values():  # before any work
            check_cache(bench, cache, overwrite=overwrite)
        evs: dict[str, Evaluation] = {}
        seconds, provenance, reports = {}, {}, {}
        for name, bench in benches.items():
            p = prepare(bench, data, cache, overwrite=overwrite)  # other descriptors: in cache/descriptors/NAME
            split_evs = evaluate_splits(p, bench.eval_config())
            evs.update({f"{split} {name}": e for split, e in split_evs.items()})
            seconds[name], provenance[name] = p.seconds, p.ds.reference.provenance
            reports[name] = (split_evs["test"], p.ds.split("test"))
        first = reports[conf.descriptors[0]]
        header = ["method", *(f"R@1 {k}" for k in evs)]
        rows = recall_table(evs, conf.methods)
        results = {"experiment": "descriptors", "recall@1": recall_at_1(evs, conf.methods),
                   "descriptors": {d: conf.describe(d).to_dict() for d in conf.descriptors},
                   "details": {k: summary(e) for k, e in evs.items()}, "timings_s": seconds, "provenance": provenance}
        md = (f"# Descriptors ({', '.join(conf.descriptors)}; CNN input {conf.cnn_size[0]}×{conf.cnn_size[1]})\n\n"
              "Recall@1; the whole pipeline (PCA, S_L and S_1 trained) per descriptor.\n\n"
              + markdown_table(header, rows) + "\nThe paper's table (test split):\n\n"
              + side_by_side(TABLE_S3, conf.descriptors,
                             recall_lookup([evs[f"test {d}"].results["methods"] for d in conf.descriptors]),
                             conf.benchmark.recall_denominator))
        o = Outputs("descriptors", results, md, descriptors_figure(rows, list(evs), conf.descriptors),
                    [table_section("experiment", "Descriptors", {"Recall@1": (header, rows)}, "Per-descriptor "
                                   "reports: " + ", ".join(f"{d}/report.html" for d in conf.descriptors))],
                    first, evs)
        return write_outputs(o, conf, data, out, "Experiment: single-image descriptors", overwrite,
                             lambda tmp: write_reports(reports, data, tmp))


def write_reports(reports: dict[str, tuple[Evaluation, Dataset]], data: str | Path, out: Path) -> None:
    """``NAME/report.html``: the test evaluation of each descriptor."""
    for name, (ev, ds) in reports.items():
        write_html_report(ev, ds, out / name / "report.html",
                          report_config(data, f"Nordland64 with {name} descriptors, test"))


def descriptors_figure(rows: list[list], columns: list[str], names: tuple[str, ...]) -> object:
    """Grouped bars: test R@1 of every method, one bar per descriptor."""
    fig, ax = new_figure(10, 4.5)
    width = 0.8 / len(names)
    x = np.arange(len(rows))
    for i, (name, colour) in enumerate(zip(names, method_colours(len(names)), strict=True)):
        col = 1 + columns.index(f"test {name}")
        ax.bar(x + (i - (len(names) - 1) / 2) * width, [r[col] or 0.0 for r in rows], width, label=name, color=colour)
    ax.set_xticks(x, [r[0] for r in rows], rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("test Recall@1")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=8)
    ax.set_title("Single-image descriptors through the whole pipeline")
    return fig
