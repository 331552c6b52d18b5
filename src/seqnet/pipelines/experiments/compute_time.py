"""``seqnet experiment compute-time`` (the paper's Table II, "Computation Time"): S_1 and S_5 descriptor
extraction, whole-map SeqMatch and SeqMatch over the HVPR top 20, per query, on a map of the paper's
size (14,000 references, D = 4096, L_m = 5), measured the paper's way and end to end, beside the
paper's GTX 1080 Ti figures.

The timing itself is ``seqnet benchmark timing`` (:mod:`seqnet.pipelines.timing`: a synthetic map in a
temporary folder, every measurement in a fresh process); its full output goes to ``OUT/timing``, which
appears together with the table. The
models are untrained SeqNets of the paper's size: time does not depend on the weights. No data folder
is read.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from ...core.config import Config
from ...core.stage import Written
from ...report.paper import TABLE_II
from ...report.tables import method_colours, new_figure
from ...security.locks import locked
from ..outputs import write_outputs as write_folder
from ..timing import TimingConfig
from ..timing.report import paper_table, table_ii
from .common import Outputs, check_experiment, kind_of, table_section, write_files

PAPER_SIZE = TimingConfig(sizes=(14000,), dims=(4096,), seq_lens=(5,), top_ks=(20,), indexes=(), queries=30,
                          float16_recall=False)


def timing_main(conf: TimingConfig, out: Path) -> Written:
    """``seqnet benchmark timing``'s stage (imported when run: it needs torch): ``out/results.json`` and its data."""
    from ..timing.run import main as run

    return run(conf, out)


@dataclasses.dataclass(frozen=True)
class ComputeTimeConfig(Config):
    """Settings of the compute-time table: the timing sweep (default the paper's map size, exact search only)."""

    timing: TimingConfig = PAPER_SIZE


def main(conf: ComputeTimeConfig, data: str | Path | None, out: str | Path, cache: str | Path | None = None,
         overwrite: bool = False) -> Path:
    """Time it; writes ``timing/`` (the timing stage's output), ``results.json``, ``results.md``,
    ``compute_time.png``, ``report.html`` and ``config.json`` to ``out``, together (the timing runs in the
    new version's folder) (``data``, ``cache``: unused)."""
    out = Path(out)
    with locked(out):
        check_experiment(out, "compute_time", overwrite, ("timing",))

        def write(tmp: Path) -> None:
            res = timing_main(conf.timing, tmp / "timing").data  # what the stage wrote to timing/results.json
            write_files(outputs(res), conf, data or "", tmp, "Experiment: computation time (paper Table II)")

        write_folder(out, kind_of("compute_time"), "experiment's outputs", write, overwrite)
    return out / "results.json"


def outputs(res: dict[str, Any]) -> Outputs:
    """The experiment's outputs from the timing stage's results."""
    c = res["config"]
    seq_len, top_k = c["seq_lens"][-1], c["top_ks"][-1]
    e = next(m for m in res["maps"] if m["dim"] == max(c["dims"]) and m["n_db"] == max(c["sizes"]))
    ours = table_ii(e, seq_len, top_k)
    md = (f"# Computation time (paper: Table II)\n\n{res['machine']['platform']}, {c['threads']} threads, device "
          f"{c['device']}, {c['queries']} queries one at a time; load average {e['loadavg']}.\n\n"
          + paper_table(e, seq_len, top_k))
    results = {"experiment": "compute-time", "paper_table": TABLE_II.key, "n_db": e["n_db"], "dim": e["dim"],
               "seq_len": seq_len, "top_k": top_k, "ms": ours, "timing": "timing/results.json",
               "provenance": None}
    header = ["", *TABLE_II.columns]
    rows = [["paper", *TABLE_II.rows[0].values],
            *([f"ours, {k}", *("–" if v is None else f"{v[0]:.2f}" for v in r.values())] for k, r in ours.items())]
    return Outputs("compute_time", results, md, time_figure(ours),
                   [table_section("experiment", "Computation time (Table II)", {"ms per query": (header, rows)},
                                  f"N_db = {e['n_db']:,}, D = {e['dim']}; the full timing is in timing/results.md.")])


def paper_ms() -> list[float]:
    """The paper's Table II means (ms)."""
    return [float(v.split("±")[0]) for v in TABLE_II.rows[0].values]


def time_figure(ours: dict[str, dict[str, Any]]) -> object:
    """Bars, log scale: the paper's ms per query and ours (the paper's way, end to end) per column."""
    fig, ax = new_figure(8, 4.2)
    series = {"paper (GTX 1080 Ti)": paper_ms(),
              **{f"ours, {k}": [np.nan if v is None else v[0] for v in r.values()] for k, r in ours.items()}}
    width = 0.8 / len(series)
    x = np.arange(len(TABLE_II.columns))
    for i, ((name, ys), colour) in enumerate(zip(series.items(), method_colours(len(series)), strict=True)):
        ax.bar(x + (i - (len(series) - 1) / 2) * width, ys, width, label=name, color=colour)
    ax.set_xticks(x, TABLE_II.columns)
    ax.set_yscale("log")
    ax.set_ylabel("ms per query")
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=8)
    ax.set_title("Computation time per query (paper Table II)")
    return fig
