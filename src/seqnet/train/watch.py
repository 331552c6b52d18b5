"""The checks that speak up before and while a run trains.

:func:`val_warning`: a val split with fewer than :data:`VAL_MIN` queries cannot choose an epoch (one query
moves R@1 by 1/n). :func:`inactive_epochs`: the epochs in a row, up to the last, in which no triplet was
active (the loop stops after ``TrainConfig.stop_inactive`` of them: :func:`inactive_message`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from ..metrics.recall import VAL_MIN
from .config import TrainConfig


def val_warning(n_val: int, val_name: str, minimum: int = VAL_MIN, resumed: bool = False) -> str | None:
    """Why a val split of ``n_val`` queries (with a positive) cannot choose an epoch, or None when it can; what to
    change: a larger val split or ``--val-split none``, in a new run when ``resumed`` (resuming keeps the split)."""
    if n_val >= minimum:
        return None
    step = f"1/{n_val} = {1 / n_val:.2f}" if n_val else "undefined"
    change = ("give a larger val split (--split val=A:B when building the dataset), or --val-split none to keep the "
              "last epoch (best.pt = last.pt)")
    if resumed:
        change = f"a resumed run keeps its val split; in a new run, {change}"
    return (f"the val split {val_name} has {n_val} queries with a positive and a full window; choosing the best "
            f"epoch needs about {minimum} or more (one query moves val R@1 by {step}). best.pt is still the epoch "
            f"of the best val R@1 (ties: the earliest), which on so few queries is mostly chance; {change}")


def inactive_epochs(history: Sequence[Mapping[str, Any]]) -> int:
    """The epochs in a row, up to the last of ``history``, without an active triplet."""
    return next((i for i, h in enumerate(reversed(history)) if float(h.get("active", 1.0)) > 0), len(history))


def inactive_message(history: Sequence[Mapping[str, Any]], conf: TrainConfig, n_queries: int,
                     best_epoch: int = 0) -> str:
    """Why training stops after ``conf.stop_inactive`` epochs without an active triplet, and what to change:
    a model that had active triplets before has learnt (separated) its training queries, which more or harder
    training data would change; one that never had any was given data too easy for the margin."""
    n, last = inactive_epochs(history), history[-1]
    triplets = int(last.get("triplets", 0))
    why = (f"{triplets} triplets were mined, none with a positive loss" if triplets else "every training triplet is "
           f"satisfied (no query had a negative within its positive's distance + the margin {conf.margin:g})")
    head = (f"stopping after epoch {last['epoch']}: no active triplet for {n} epochs in a row "
            f"(stop_inactive={conf.stop_inactive}); {why}, so the model no longer learns. ")
    kept = _kept(history, best_epoch) if conf.validates else "best.pt = last.pt (no validation)"
    radius = "the dataset's" if conf.neg_radius is None else f"{conf.neg_radius:g}"
    harder = (f"a larger --margin (now {conf.margin:g}) or harder negatives: a smaller --neg-radius (now {radius}; "
              "references farther than it are negatives)")
    if len(history) > n:  # active until the epoch before this run of inactive ones: the model learnt them
        return (head + f"It has separated its {n_queries} training queries (active triplets until epoch "
                f"{history[-n - 1]['epoch']}); {kept}. To learn more: more training queries (a larger train split), "
                f"or {harder}")
    return (head + f"No triplet was active from the first epoch: the {n_queries} training queries are too easy for "
            f"the margin; try {harder}, or a larger train split; {kept}")


def _kept(history: Sequence[Mapping[str, Any]], best_epoch: int) -> str:
    """What best.pt holds: the epoch of the best val R@1, and whether val R@1 was still rising at the stop."""
    scores = {int(h["epoch"]): float(h["recall@1"]) for h in history if "recall@1" in h}
    if best_epoch not in scores:
        return "best.pt holds the epoch of the best val R@1"
    rising = " (the last: val R@1 was still rising)" if best_epoch == int(history[-1]["epoch"]) else ""
    return f"best.pt holds epoch {best_epoch}{rising}, val R@1 {scores[best_epoch]:.4f}"
