"""The checks of a training split said before any epoch (``seqnet train``): queries that are copies of
references (:func:`seqnet.data.sanity.copied_queries`: val would score 1.000, a model of nothing), and a query
traverse that runs opposite to the reference (:func:`seqnet.methods.route.reversed_route`, the check ``seqnet
eval`` warns with), on which a sequence model learns from windows whose frames are compared in the wrong order."""

from __future__ import annotations

from ..data.sanity import copied_queries
from ..data.traverse import Dataset
from ..methods.route import reversed_route
from ..metrics.recall import ground_truth
from .config import TrainConfig


def route_warning(train_ds: Dataset, conf: TrainConfig) -> str | None:
    """The line for training on ``train_ds`` with ``conf`` when its query traverse (or some query sequences) runs
    opposite to the reference and the model compares windows of several frames (``window_len > 1``); None
    otherwise."""
    if conf.window_len <= 1:
        return None
    q, r = train_ds.query, train_ds.reference
    truth = ground_truth(q.positions, r.positions, train_ds.radius, train_ds.positives, require=False)
    said = reversed_route(truth, ["seqnet"], q.seq_bounds)
    if said is None:
        return None
    return f"{said}; a sequence model trained on these windows learns their frames in the wrong order"


def split_warnings(train_ds: Dataset, conf: TrainConfig) -> list[str]:
    """Every line of this module's checks on the train split ``train_ds`` of ``conf``, each naming the split."""
    found = [copied_queries(train_ds), route_warning(train_ds, conf)]
    return [f"training on the {conf.train_split!r} split: {line}" for line in found if line]
