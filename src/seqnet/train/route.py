"""The checks of a training split said before any epoch (``seqnet train``): queries that are copies of
references (:func:`seqnet.data.sanity.copied_queries`: val would score 1.000, a model of nothing), and a query
traverse that runs opposite to the reference (:func:`seqnet.methods.route.reversed_route`, the check ``seqnet
eval`` warns with), on which a sequence model learns from windows whose frames are compared in the wrong order; and a
train or val split that holds queries of the test split (:func:`holds_test_queries`)."""

from __future__ import annotations

from ..data.sanity import copied_queries
from ..data.traverse import Dataset
from ..methods.checks import named_test_split
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


def holds_test_queries(dataset: Dataset, conf: TrainConfig) -> list[str]:
    """One line for each split of ``conf`` that holds queries of ``dataset``'s test split: the epoch chosen on them
    (``--val-split``) or trained on (``--train-split``) makes the test numbers optimistic; said before any epoch,
    whether the split is named ``test`` or is a range or another split over its queries."""
    out = []
    if conf.validates and conf.val_split.lower() == "test":  # the user's Test too
        out.append(f"--val-split {conf.val_split}: choosing the epoch on the test split makes its test numbers "
                   "optimistic (hint: --val-split val)")
    test = named_test_split(dataset.splits)
    if test is None:
        return out
    ta, tb = dataset.ranges(test)["query"]
    for what, split in (("train", conf.train_split), ("val", conf.val_split if conf.validates else None)):
        rng = None if split is None or (what == "val" and split.lower() == "test") else dataset.ranges(split)
        if rng is None:  # no validation, or val named test (said above)
            continue
        a, b = rng["query"]
        both = max(0, min(b, tb) - max(a, ta))
        if not both:
            continue
        own = dataset.ranges(what) if what in dataset.splits and what != split else None
        apart = own is not None and min(own["query"][1], tb) <= max(own["query"][0], ta)
        hint = f"--{what}-split {what}" if apart else f"--{what}-split A:B, a range outside {ta}:{tb}"
        done = ("choosing the epoch on them makes its test numbers optimistic" if what == "val" else
                "the model trains on them, so its test numbers are not a test")
        shown = split if split == f"{a}:{b}" else f"{split} (queries {a}:{b})"
        out.append(f"--{what}-split {shown} holds {both} of the {tb - ta} queries of the test split "
                   f"{test!r} ({ta}:{tb}): {done} (hint: {hint})")
    return out
