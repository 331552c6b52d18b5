"""``seqnet experiment seeds``: the whole benchmark (S_L and S_1 trained, every method evaluated on
val and test) for several training seeds, reported as mean ± standard deviation per method.

The seed sets the initialisation and every random draw of training of both models
(:class:`~seqnet.train.TrainConfig.seed`); the descriptors are the same for every seed. The models
of the benchmark's own seed are the benchmark's (``CACHE/models``); the others are cached in
``CACHE/seeds/seedN`` (under ``CACHE/descriptors/METHOD`` for another descriptor).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ...core.config import Config, check_ints
from ...eval.evaluation import Evaluation
from ...report.tables import method_colours, new_figure
from ..nordland64 import Nordland64Config
from .common import (
    Outputs,
    check_cache,
    check_experiment,
    evaluate_splits,
    locked_dirs,
    markdown_table,
    prepare,
    summary,
    table_section,
    write_outputs,
)


@dataclasses.dataclass(frozen=True)
class SeedsConfig(Config):
    """Settings of the seeds experiment: the benchmark's and the training seeds."""

    benchmark: Nordland64Config = Nordland64Config()
    seeds: tuple[int, ...] = (0, 1, 2)

    def __post_init__(self) -> None:
        self._set("seeds", tuple(dict.fromkeys(check_ints("seeds", self.seeds, 0))))

    def seeded(self, seed: int) -> Nordland64Config:
        """The benchmark settings with both models trained with ``seed``."""
        return self.benchmark.merge(train={"seed": seed}, train_s1={"seed": seed})

    def models_sub(self, seed: int) -> str | None:
        """Where the models of ``seed`` are cached: the benchmark's own (None) or ``seeds/seedN``."""
        bench = self.seeded(seed)
        own = bench.train == self.benchmark.train and bench.train_s1 == self.benchmark.train_s1
        return None if own else f"seeds/seed{seed}"


def mean_std(values: list[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (0 for one value)."""
    a = np.asarray(values, dtype=np.float64)
    return float(a.mean()), float(a.std(ddof=1)) if len(a) > 1 else 0.0


def main(conf: SeedsConfig, data: str | Path, out: str | Path, cache: str | Path | None = None,
         overwrite: bool = False) -> Path:
    """Run the experiment; writes ``results.json``, ``results.md``, ``seeds.png``, ``report.html`` (the
    first seed's test evaluation) and ``config.json`` to ``out``."""
    out = Path(out)
    cache = Path(cache) if cache else out
    with locked_dirs(out, cache):
        check_experiment(out, "seeds", overwrite)
        for seed in conf.seeds:  # before any work
            check_cache(conf.seeded(seed), cache, conf.models_sub(seed), overwrite)
        runs: dict[int, dict[str, Evaluation]] = {}
        seconds = {}
        for seed in conf.seeds:
            bench = conf.seeded(seed)
            p = prepare(bench, data, cache, conf.models_sub(seed), overwrite)
            runs[seed], seconds[seed] = evaluate_splits(p, bench.eval_config()), p.seconds
        methods = list(conf.benchmark.methods)
        stats = {split: {m: mean_std([runs[s][split].results["methods"][m]["recall@1"] for s in conf.seeds])
                         for m in methods} for split in ("val", "test")}
        header = ["method", "val R@1 mean", "val std", "test R@1 mean", "test std",
                  *(f"test seed {s}" for s in conf.seeds)]
        rows = [[m, *stats["val"][m], *stats["test"][m],
                 *(runs[s]["test"].results["methods"][m]["recall@1"] for s in conf.seeds)] for m in methods]
        results = {"experiment": "seeds", "seeds": list(conf.seeds),
                   "recall@1": {split: {m: {"mean": v[0], "std": v[1]} for m, v in st.items()}
                                for split, st in stats.items()},
                   "per_seed": {str(s): {split: summary(e) for split, e in runs[s].items()} for s in conf.seeds},
                   "timings_s": {str(s): v for s, v in seconds.items()}, "provenance": p.ds.reference.provenance}
        md = (f"# Seeds ({len(conf.seeds)}: {', '.join(map(str, conf.seeds))})\n\nRecall@1 mean ± sample standard "
              "deviation over the training seeds.\n\n" + markdown_table(header, rows))
        first = conf.seeds[0]
        o = Outputs("seeds", results, md, seeds_figure(rows, len(conf.seeds)),
                    [table_section("experiment", "Seeds", {"Recall@1 over seeds": (header, rows)},
                                   f"{len(conf.seeds)} training seeds; the report below is seed {first}'s test.")],
                    (runs[first]["test"], p.ds.split("test")),
                    {f"{split} seed {s}": e for s in conf.seeds for split, e in runs[s].items()})
        return write_outputs(o, conf, data, out, f"Experiment: {len(conf.seeds)} seeds", overwrite)


def seeds_figure(rows: list[list], n_seeds: int) -> object:
    """Test R@1 per method: mean ± std bars and each seed as a dot."""
    fig, ax = new_figure(8, 4.5)
    x = np.arange(len(rows))
    colours = method_colours(len(rows))
    ax.bar(x, [r[3] for r in rows], yerr=[r[4] for r in rows], color=colours, capsize=3, alpha=0.8)
    for i, r in enumerate(rows):
        ax.scatter(np.full(n_seeds, i), r[5:], color="black", s=8, zorder=3)
    ax.set_xticks(x, [r[0] for r in rows], rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("test Recall@1")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3, axis="y")
    ax.set_title(f"Benchmark over {n_seeds} training seeds (mean ± std, dots: seeds)")
    return fig
