"""The table of experiments (:class:`Experiment`): each one's configuration, stage and paper table; `tables`
(which runs the others) is added by the package."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from pathlib import Path

from ...core.config import Config
from . import comparison, compute_time, descriptors, longer, reverse, seeds, splits, tsne


@dataclasses.dataclass(frozen=True)
class Experiment:
    """One entry of :data:`EXPERIMENTS`: its configuration class, stage, one-line summary, the paper table
    it reproduces (``I``, ``II``, ``III``, ``S1``–``S3``; None: not a table), whether it reads the
    nordland64 data (``compute-time`` times a synthetic map of the paper's size) and whether it runs on a user's
    seqnet dataset with its models instead (the evaluation-only tables: I, III, S2)."""

    config: type[Config]
    run: Callable[..., Path]
    summary: str
    paper: str | None = None
    data: bool = True
    own_data: bool = False  # also runs on a user's seqnet dataset and models (``dataset=``, ``models=``)

    @property
    def alias(self) -> str | None:
        """The name of its paper table as a command (``table-1``, ``table-s2``, …)."""
        if self.paper is None:
            return None
        roman = {"I": "1", "II": "2", "III": "3"}
        return f"table-{roman.get(self.paper, self.paper.lower())}"

    def start(self, conf: Config, out: str | Path, data: str | Path | None = None, cache: str | Path | None = None,
              dataset: str | Path | None = None, models: Sequence[str | Path] = (), overwrite: bool = False) -> Path:
        """Run the stage with the inputs it reads: none (``compute-time``), the nordland64 ``data`` and
        ``cache``, or also a user's ``dataset`` and ``models`` (:attr:`own_data`); ``overwrite``: replace
        outputs (and cache entries) in ``out`` that this experiment did not write."""
        if not self.data:
            return self.run(conf, None, out, overwrite=overwrite)
        if self.own_data:
            return self.run(conf, data, out, cache, dataset=dataset, models=models, overwrite=overwrite)
        return self.run(conf, data, out, cache, overwrite=overwrite)


PAPER_EXPERIMENTS: dict[str, Experiment] = {  # every experiment but `tables`, which runs them
    "comparison": Experiment(comparison.ComparisonConfig, comparison.main,
                             "every method of the paper's comparison, R@1/5/20 and Recall@K curves (paper Table I)",
                             "I", own_data=True),
    "compute-time": Experiment(compute_time.ComputeTimeConfig, compute_time.main,
                               "per-query time at the paper's map size, 14k x 4096 (paper Table II)", "II",
                               data=False),
    "reverse": Experiment(reverse.ReverseConfig, reverse.main,
                          "reference in reverse order: vanilla vs reverse SeqMatch, S_L as trained (paper Table III)",
                          "III", own_data=True),
    "splits": Experiment(splits.SplitsConfig, splits.main, "reference / query sizes of each split (paper Table S1)",
                         "S1"),
    "longer-sequences": Experiment(longer.LongerConfig, longer.main,
                                   "HVPR with S_L and longer re-ranking sequences L_m (5, 10, 20; paper Table S2)",
                                   "S2", own_data=True),
    "descriptors": Experiment(descriptors.DescriptorsConfig, descriptors.main,
                              "the whole pipeline on pixels, NetVLAD and GMP descriptors (paper Table S3)", "S3"),
    "tsne": Experiment(tsne.TsneConfig, tsne.main, "t-SNE of raw, smoothing, Delta, S_1 and S_L descriptors "
                       "(the paper's t-SNE figure)"),
    "seeds": Experiment(seeds.SeedsConfig, seeds.main, "the benchmark over several training seeds, mean ± std"),
}
