"""The paper's supplementary experiments on the Nordland64 benchmark, one module each, as stages
``main(conf, data, out, cache=None) -> Path`` (``results.json``):

* ``reverse`` (:mod:`.reverse`): the reference in reverse order, vanilla vs reverse SeqMatch (the
  paper's Table III, "Reverse Traverse");
* ``longer-sequences`` (:mod:`.longer`): HVPR with S_L and L_m = 5, 10, 20 (supplementary "Longer
  Sequences", S2);
* ``descriptors`` (:mod:`.descriptors`): the whole pipeline on pixels, NetVLAD, GMP (supplementary
  "Different Single Image Descriptor", S3);
* ``tsne`` (:mod:`.tsne`): t-SNE of raw, smoothing, Delta, S_1, S_L descriptors of the test split
  (the supplementary t-SNE figure);
* ``seeds`` (:mod:`.seeds`): the benchmark over several training seeds, mean ± std.

Each writes ``results.json``, ``results.md``, its figure, ``report.html`` and ``config.json``;
descriptors and models are cached as the benchmark caches them (:mod:`.common`). See
docs/experiments.md.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

from ...core.config import Config
from . import descriptors, longer, reverse, seeds, tsne


@dataclasses.dataclass(frozen=True)
class Experiment:
    """One entry of :data:`EXPERIMENTS`: its configuration class, stage and one-line summary."""

    config: type[Config]
    run: Callable[..., Path]
    summary: str


EXPERIMENTS: dict[str, Experiment] = {
    "reverse": Experiment(reverse.ReverseConfig, reverse.main,
                          "reference in reverse order: vanilla vs reverse SeqMatch, S_L as trained (paper Table III)"),
    "longer-sequences": Experiment(longer.LongerConfig, longer.main,
                                   "HVPR with S_L and longer re-ranking sequences L_m (5, 10, 20)"),
    "descriptors": Experiment(descriptors.DescriptorsConfig, descriptors.main,
                              "the whole pipeline on pixels, NetVLAD and GMP descriptors (paper table S3)"),
    "tsne": Experiment(tsne.TsneConfig, tsne.main, "t-SNE of raw, smoothing, Delta, S_1 and S_L descriptors"),
    "seeds": Experiment(seeds.SeedsConfig, seeds.main, "the benchmark over several training seeds, mean ± std"),
}

__all__ = ["EXPERIMENTS", "Experiment"]
