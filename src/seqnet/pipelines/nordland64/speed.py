"""Variable-speed query traverses: the winter traverse re-sampled with a smooth, seeded speed profile.

The reference (summer) keeps one frame per place. The query is re-sampled so that it moves at
``v(t)`` reference frames per query frame, with ``v`` between A and B: query frame ``t`` shows the
original frame ``round(s_t)`` (half up), ``s_0 = 0``, ``s_{t+1} = s_t + v(t)``, until ``s`` passes
the last frame; so frames are dropped where ``v > 1`` and repeated where ``v < 1``. Each kept frame
keeps its descriptor, name and position, so the ground truth stays exact.

The profile: knots every :data:`SPEED_PERIOD` query frames with speeds drawn log-uniformly in
``[A, B]`` (so 0.5:2 is as often half as double speed), joined by cosine interpolation (smooth,
never outside ``[A, B]``). ``A = B = 1`` gives the original traverse. A traverse with sequence
bounds is re-sampled sequence by sequence.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ...core.errors import ConfigError
from ...data import resample
from ...data.traverse import Dataset, Traverse
from ...sequence.windows import check_speed_range

SPEED_PERIOD = 40  # query frames between two knots of the speed profile


def check_speed(speed: tuple[float, float] | list[float]) -> tuple[float, float]:
    """``(A, B)`` with ``0 < A <= B`` (finite): :func:`seqnet.sequence.windows.check_speed_range`."""
    return check_speed_range("query_speed", speed)


def speed_profile(n: int, speed: tuple[float, float], rng: np.random.Generator,
                  period: int = SPEED_PERIOD) -> np.ndarray:
    """``[n]`` speeds in ``[A, B]``: log-uniform knots every ``period`` frames, cosine-interpolated."""
    lo, hi = check_speed(speed)
    knots = np.exp(rng.uniform(np.log(lo), np.log(hi), n // period + 2))
    t = np.arange(n) / period
    k = np.floor(t).astype(np.int64)
    w = (1 - np.cos(np.pi * (t - k))) / 2
    return np.clip(knots[k] * (1 - w) + knots[k + 1] * w, lo, hi)


def resample_indices(n_frames: int, speed: tuple[float, float], rng: np.random.Generator,
                     period: int = SPEED_PERIOD) -> np.ndarray:
    """Original frame (``0 .. n_frames − 1``) of each query frame of the re-sampled traverse."""
    lo, _ = check_speed(speed)
    v = speed_profile(int(np.ceil(n_frames / lo)) + 2, speed, rng, period)
    s = np.concatenate([[0.0], np.cumsum(v)])
    idx = np.floor(s + 0.5).astype(np.int64)
    return idx[idx < n_frames]


def resample_traverse(t: Traverse, speed: tuple[float, float], seed: int | list[int]) -> Traverse:
    """``t`` re-sampled at ``speed`` (sequence by sequence when it has sequence bounds): the frames of
    :func:`resample_indices` through :func:`seqnet.data.resample.resample_traverse`."""
    rng = np.random.default_rng(seed)
    parts = [(0, len(t))] if t.seq_bounds is None else sorted({(int(a), int(b)) for a, b in t.seq_bounds})
    idx = np.concatenate([a + resample_indices(b - a, speed, rng) for a, b in parts])
    return dataclasses.replace(resample.resample_traverse(t, idx), name=f"{t.name} (speed {speed[0]:g}:{speed[1]:g})")


def variable_speed(ds: Dataset, speed: tuple[float, float] | None, seed: int | list[int]) -> Dataset:
    """``ds`` with its query traverse re-sampled at ``speed`` (None: ``ds`` unchanged); positives are
    not supported (the ground truth is the radius around each kept frame's own position)."""
    if speed is None:
        return ds
    if ds.positives is not None:
        raise ConfigError(f"dataset {ds.name!r} has explicit positives; variable-speed re-sampling supports the "
                          "radius ground truth only")
    return dataclasses.replace(ds, query=resample_traverse(ds.query, check_speed(speed), seed), splits={})
