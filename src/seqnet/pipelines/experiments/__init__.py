"""The SeqNet paper's tables and figures on the Nordland64 benchmark, one module each, as stages
``main(conf, data, out, cache=None) -> Path`` (``results.json``); each named also by its paper table
(``table-1`` …, :data:`EXPERIMENTS` ``paper``):

* ``comparison`` (:mod:`.comparison`, Table I): every method of the paper's comparison, R@1/5/20, and
  the Recall@K curves (Fig. 3);
* ``compute-time`` (:mod:`.compute_time`, Table II): per-query time on a map of the paper's size;
* ``reverse`` (:mod:`.reverse`, Table III): the reference in reverse order, vanilla vs reverse SeqMatch;
* ``splits`` (:mod:`.splits`, Table S1): the reference / query sizes of each split;
* ``longer-sequences`` (:mod:`.longer`, Table S2): HVPR with S_L and L_m = 5, 10, 20;
* ``descriptors`` (:mod:`.descriptors`, Table S3): the whole pipeline on pixels, NetVLAD, GMP;
* ``tsne`` (:mod:`.tsne`): t-SNE of raw, smoothing, Delta, S_1, S_L descriptors of the test split
  (the supplementary t-SNE figure);
* ``seeds`` (:mod:`.seeds`): the benchmark over several training seeds, mean ± std;
* ``tables`` (:mod:`.tables`): all of the paper's tables and the t-SNE figure in one run.

Each writes ``results.json``, ``results.md`` (with the paper's table beside ours,
:mod:`seqnet.report.paper`), its figure, ``report.html`` and ``config.json``, together, replacing only its
own earlier outputs (:mod:`seqnet.pipelines.outputs`); descriptors and models are cached as the benchmark
caches them (:mod:`.common`). See docs/experiments.md.
"""

from __future__ import annotations

from . import tables
from .registry import PAPER_EXPERIMENTS, Experiment

EXPERIMENTS: dict[str, Experiment] = {
    **PAPER_EXPERIMENTS,
    "tables": Experiment(tables.TablesConfig, tables.main, "every table of the paper and its t-SNE figure in one run "
                         "(OUT/table-1 ..., one results.md)"),
}

__all__ = ["EXPERIMENTS", "Experiment"]
