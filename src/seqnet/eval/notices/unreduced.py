"""The model-free counterparts of the learned methods on the user's own, unreduced descriptors, when the evaluated
dataset is a ``seqnet train --pca`` reduction of another (``<DIR>-pca<D>`` beside ``<DIR>``:
:func:`seqnet.describe.pca.unreduced_source`). The PCA may cost the model-free methods more than a learned method
gains back: compared on the reduced descriptors only, a learned pipeline below the user's own baseline looks like a
win. :func:`unreduced_counterparts` evaluates the counterparts there once, on the same queries, and keeps their
recalls in each counterpart's entry (``unreduced``), which :func:`seqnet.report.guidance.learned_below_baseline`
compares with (the tables' marks too: they read the method entries)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ...core.errors import SeqnetError
from ...core.log import logger
from ...report.guidance import counterparts
from ..config import EvalConfig
from ..evaluation import Evaluation

if TYPE_CHECKING:
    from ...data.traverse import Dataset


def unreduced_counterparts(ev: Evaluation, ds: Dataset, split: str, conf: EvalConfig,
                           source: str | Path | None) -> dict[str, Any] | None:
    """``{name: {"dataset": DIR, "dims": [D unreduced, D reduced], "recall@K": r, ..., "queries": n}}``: the
    model-free counterparts of ``ev``'s learned methods evaluated on the unreduced dataset ``source`` was reduced
    from, on the same ``split`` (same query range, windows and settings; each kept in its own entry of
    ``ev.results["methods"]`` as ``unreduced``); None when no learned method has a counterpart evaluated, ``source``
    is not a found reduction, or the unreduced dataset's ranges differ (said at DEBUG)."""
    methods = ev.results.get("methods") or {}
    wanted = tuple(dict.fromkeys(b for n in methods for b in counterparts(n, methods)))
    if source is None or not wanted or (ev.results.get("config") or {}).get("index"):
        return None
    from ...describe.pca import unreduced_source  # here: the describe package loads with it

    parent = unreduced_source(source)
    if parent is None:
        return None
    from ...data.io import load_dataset
    from ..score import score

    try:
        full = load_dataset(parent)
        if full.ranges(split) != ds.ranges(split) or len(full.query) != len(ds.query):
            logger.debug("not comparing with the unreduced %s: its %r split differs", parent, split)
            return None
        cfg = ev.results.get("config") or {}
        base = score(full.split(split), conf.merge(methods=wanted, seq_len=cfg.get("seq_len", conf.seq_len),
                                                     match_len=cfg.get("match_len", conf.match_len),
                                                     target_precision=None), {})
    except SeqnetError as e:
        logger.debug("not comparing with the unreduced %s: %s", parent, e)
        return None
    where = {"dataset": str(parent), "dims": [full.query.dim, ds.query.dim]}
    out = {n: {**where, **recalls(e)} for n, e in base.results["methods"].items()}
    for n, entry in out.items():
        methods[n]["unreduced"] = entry
    return out


def recalls(entry: Mapping[str, Any]) -> dict[str, Any]:
    """The Recall@K values and the scored queries of a method's entry."""
    return {k: v for k, v in entry.items() if k.startswith("recall@") or k == "queries"}
