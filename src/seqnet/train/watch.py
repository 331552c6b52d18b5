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


def val_warning(n_val: int, val_name: str, minimum: int = VAL_MIN) -> str | None:
    """Why a val split of ``n_val`` queries (with a positive) cannot choose an epoch, or None when it can."""
    if n_val >= minimum:
        return None
    step = f"1/{n_val} = {1 / n_val:.2f}" if n_val else "undefined"
    return (f"the val split {val_name} has {n_val} queries with a positive and a full window; choosing the best "
            f"epoch needs about {minimum} or more (one query moves val R@1 by {step}). best.pt is still the epoch "
            "of the best val R@1 (ties: the earliest), which on so few queries is mostly chance; give a larger "
            "val split (--split val=A:B when building the dataset), or --val-split none to keep the last epoch "
            "(best.pt = last.pt)")


def inactive_epochs(history: Sequence[Mapping[str, Any]]) -> int:
    """The epochs in a row, up to the last of ``history``, without an active triplet."""
    return next((i for i, h in enumerate(reversed(history)) if float(h.get("active", 1.0)) > 0), len(history))


def inactive_message(history: Sequence[Mapping[str, Any]], conf: TrainConfig, n_queries: int) -> str:
    """Why training stops after ``conf.stop_inactive`` epochs without an active triplet, and what to change."""
    n, last = inactive_epochs(history), history[-1]
    triplets = int(last.get("triplets", 0))
    why = ("no query had a negative closer than its positive + the margin: every triplet is already satisfied"
           if triplets == 0 else f"{triplets} triplets were mined but none had a positive loss")
    return (f"stopping after epoch {last['epoch']}: no active triplet for {n} epochs in a row "
            f"(stop_inactive={conf.stop_inactive}); {why}, so the model no longer learns. Likely: too little or "
            f"too easy training data ({n_queries} queries); try a larger train split, a larger --margin (now "
            f"{conf.margin:g}) or more negatives: a smaller --neg-radius (now {conf.neg_radius}; references "
            "farther than it are negatives); best.pt is kept")
