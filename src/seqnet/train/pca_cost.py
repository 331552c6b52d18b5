"""What the PCA the training guide would advise costs, measured before it is advised (:func:`pca_advice`).

A PCA sized from shapes alone (D against the training windows) can cost the descriptors more than the smaller
layer gains back (the session-52 own-data test: ``--pca 128`` lowered single R@1 0.280 -> 0.120 and S_5's
0.381 -> 0.238). So the guide fits the PCA it would advise on the train split's frames, evenly spaced as ``--pca``
fits it (at most :data:`FIT_MOST`; ``--pca`` itself: 20000), and scores the model-free methods :data:`MEASURED`
(no model: cheap) on the val split (the train split without validation) before and after projecting, with the
evaluation's own scoring (:func:`seqnet.eval.score.score`: the numbers ``seqnet eval`` gives on that split of the
``--pca`` dataset and, on the unreduced one, :mod:`seqnet.eval.notices.unreduced`'s). Time is bounded: at most
:data:`SCORE_MACS` query x reference x D multiply-adds (fewer queries beyond, said in the message).

On a dataset already reduced by a PCA (``extra["pca"]``), the advice names the unreduced dataset it came from
(:func:`seqnet.describe.pca.unreduced_source`) and measures there: a second PCA would reduce twice.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

from ..core.errors import SeqnetError
from ..core.log import logger
from ..data.traverse import Dataset
from ..describe.pca import PCA, fit_pca, spread_frames, unreduced_source
from .config import TrainConfig

MEASURED = ("single", "raw+seqmatch")  # the model-free methods measured before and after the PCA
FIT_MOST = 4000  # train frames the measured PCA is fitted on at most (evenly spaced, as --pca picks its 20000)
SCORE_MACS = 2e10  # query x reference x D multiply-adds of one measurement at most (fewer queries beyond)
MIN_QUERIES = 50  # queries measured at least (when the split has them)


@dataclasses.dataclass(frozen=True)
class PcaCost:
    """Recall@1 of :data:`MEASURED` on the split ``split`` (of dataset ``dataset``) with its ``in_dims``-D
    descriptors (``before``) and after a PCA to ``dims`` fitted on ``fitted`` of the train split's ``frames``
    frames (``after``); ``queries``: the queries each was scored on; ``cut``: the query range when the split's
    was cut to bound the time ("" when whole)."""

    dims: int
    in_dims: int
    dataset: str
    split: str
    before: dict[str, float]
    after: dict[str, float]
    queries: dict[str, int]
    fitted: int
    frames: int
    cut: str = ""

    @property
    def cheap(self) -> bool:
        """Whether no measured method loses a query to the PCA."""
        return all(self.after[m] > self.before[m] - 0.5 / max(self.queries[m], 1) for m in self.before)

    def text(self) -> str:
        """``single val R@1 0.280 -> 0.120 and raw+seqmatch ... (on N val queries of DS, ...)``."""
        said = " and ".join(f"{m} {self.split} R@1 {self.before[m]:.3f} -> {self.after[m]:.3f}" for m in self.before)
        counts = " / ".join(str(self.queries[m]) for m in self.before)
        cut = f", queries {self.cut} only (time bounded)" if self.cut else ""
        fit = (f"the train split's {self.frames} frames" if self.fitted == self.frames else
               f"{self.fitted} of the train split's {self.frames} frames, evenly spaced")
        return (f"{said} (model-free, on {counts} {self.split} queries of {self.dataset}{cut}; a PCA fitted on {fit}, "
                "as --pca fits it)")


@dataclasses.dataclass(frozen=True)
class PcaAdvice:
    """The PCA to ``dims`` the guide names, what it costs (``cost``; None: not measured), and, on a dataset
    already reduced (``reduced``: its recorded ``extra["pca"]``), the unreduced dataset (``source``; None: not
    found beside it)."""

    dims: int
    cost: PcaCost | None = None
    reduced: dict | None = None
    source: str | None = None

    @property
    def advised(self) -> bool:
        """Whether to advise it: cheap in accuracy, or not measured."""
        return self.cost is None or self.cost.cheap

    @property
    def flag(self) -> str:
        """How to apply it: ``--pca D``, or, on a reduced dataset, from its unreduced source (once)."""
        if self.reduced is None:
            return f"--pca {self.dims}"
        was = f"already reduced by a PCA, {self.reduced.get('input_dim', '?')}-D to {self.reduced.get('dims', '?')}-D"
        if self.source is not None:
            return (f"seqnet train --dataset {self.source} --pca {self.dims} (this dataset is {was}: reduce the "
                    "unreduced descriptors once, not twice)")
        return (f"--pca {self.dims} on the unreduced descriptors (this dataset is {was}; rebuild without --pca, then "
                "seqnet train --pca once)")

    def cost_text(self) -> str:
        """What it would cost, when measured ("" when not)."""
        if self.cost is None:
            return ""
        how = f"seqnet train --dataset {self.source} --pca {self.dims}" if self.source else f"--pca {self.dims}"
        return f"{how} would {'keep' if self.cost.cheap else 'lower'} {self.cost.text()}"


def pca_advice(dataset: Dataset, conf: TrainConfig, dims: int, path: str | Path | None = None) -> PcaAdvice:
    """The :class:`PcaAdvice` of a PCA to ``dims`` for training ``conf`` on ``dataset`` (read from ``path``;
    default: ``dataset.path``), measured (:func:`pca_cost`) on it, or on its unreduced source when it is
    already reduced."""
    reduced = dataset.extra.get("pca") if isinstance(dataset.extra.get("pca"), dict) else None
    if reduced is None:
        return PcaAdvice(dims, pca_cost(dataset, conf, dims))
    where = path or dataset.path
    source = unreduced_source(where) if where is not None else None
    if source is None:
        return PcaAdvice(dims, None, reduced)
    from ..data.io import load_dataset

    try:
        full = load_dataset(source)
    except SeqnetError as e:
        logger.debug("not measuring the PCA on %s: %s", source, e)
        return PcaAdvice(dims, None, reduced, str(source))
    return PcaAdvice(dims, pca_cost(full, conf, dims), reduced, str(source))


def pca_cost(dataset: Dataset, conf: TrainConfig, dims: int) -> PcaCost | None:
    """:class:`PcaCost` of a PCA to ``dims`` fitted on ``conf.train_split`` of ``dataset`` (see the module
    docstring); None when it cannot be measured (no such split, too few frames, ``dims`` not below D; said at
    DEBUG)."""
    try:
        frames, total = spread_frames(dataset.split(conf.train_split), FIT_MOST)
        if not 1 <= dims < min(len(frames), dataset.query.dim):
            return None
        pca = fit_pca(frames, dims)
        del frames
    except SeqnetError as e:
        logger.debug("not measuring what --pca %d costs: %s", dims, e)
        return None
    return cost_of(dataset, conf, pca, min(total, FIT_MOST), total)


def cost_of(dataset: Dataset, conf: TrainConfig, pca: PCA, fitted: int, frames: int) -> PcaCost | None:
    """:class:`PcaCost` of the PCA ``pca`` (fitted on ``fitted`` of the train split's ``frames`` frames; the one
    ``--pca`` wrote, or :func:`pca_cost`'s) on ``dataset`` (see the module docstring: the val split, or the train
    split without validation; time bounded); None when it cannot be measured (said at DEBUG)."""
    t0 = time.perf_counter()
    try:
        name = conf.val_split if conf.validates and dataset.ranges(conf.val_split) is not None else conf.train_split
        part, cut = bounded(dataset, name)
        before, queries = _recalls(part, conf)
        after, _ = _recalls(projected(part, pca), conf)
    except SeqnetError as e:
        logger.debug("not measuring what --pca %d costs: %s", pca.dims, e)
        return None
    logger.debug("measured what --pca %d costs in %.1f s", pca.dims, time.perf_counter() - t0)
    return PcaCost(pca.dims, dataset.query.dim, dataset.name, name, before, after, queries, fitted, frames, cut)


def bounded(dataset: Dataset, split: str) -> tuple[Dataset, str]:
    """The split ``split`` of ``dataset``, its queries cut to the first ones when scoring them all would take
    more than :data:`SCORE_MACS` multiply-adds (at least :data:`MIN_QUERIES`); and the query range kept when
    cut ("" when whole)."""
    rng = dataset.ranges(split)
    (r0, r1), (q0, q1) = rng["reference"], rng["query"]
    keep = max(MIN_QUERIES, int(SCORE_MACS // max((r1 - r0) * dataset.query.dim, 1)))
    if q1 - q0 <= keep:
        return dataset.split(split), ""
    return dataset.split(f"{r0}:{r1},{q0}:{q0 + keep}"), f"{q0}:{q0 + keep} of {q0}:{q1}"


def projected(ds: Dataset, pca: PCA) -> Dataset:
    """``ds`` with both traverses' descriptors projected by ``pca`` (L2-normalised, as ``--pca`` writes them)."""
    ref, qry = (t.with_descriptors(pca.transform_blocks(t.descriptors)) for t in (ds.reference, ds.query))
    return dataclasses.replace(ds, reference=ref, query=qry)


def _recalls(ds: Dataset, conf: TrainConfig) -> tuple[dict[str, float], dict[str, int]]:
    """Recall@1 and the queries scored of each of :data:`MEASURED` on ``ds`` (windows of the model's L; S_1's:
    the evaluation's default L)."""
    from ..eval.config import EvalConfig
    from ..eval.score import score

    ev = score(ds, EvalConfig(methods=MEASURED, seq_len=conf.seq_len if conf.seq_len > 1 else None), {})
    got = ev.results["methods"]
    return {m: float(got[m]["recall@1"]) for m in MEASURED}, {m: int(got[m]["queries"]) for m in MEASURED}
