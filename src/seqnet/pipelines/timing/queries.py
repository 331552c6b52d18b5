"""The queries timed against a map: synthetic ones (written by :mod:`.synth`) or a dataset's query split."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from ...maps import Map, load_query
from ...metrics.recall import GroundTruth
from ...security.arrays import read_npy
from ...sequence.windows import window_frames, window_offset
from .config import TimingConfig
from .synth import RADIUS, random_models

if TYPE_CHECKING:
    from ...sequence.model import SeqNet



@dataclasses.dataclass
class Queries:
    """Q query items against a map.

    Attributes:
        shortlist: ``[Q, D1]`` shortlist descriptors; frames: ``[Nf, D2]`` re-ranking frame descriptors
            holding every query's window; centres: ``[Q]`` frame (in ``frames``) of each query item.
        raw: ``[Q, L, D]`` raw descriptors of each item's L-window (what S_L / S_1 read; for describe timings).
        stream: ``[S, D2]`` contiguous frames for the online and batch whole-map matchers.
        truth: ground truth over the map's items; frame_truth: over its frames (single-image k-NN).
        models: S_L (``seqnet``) and S_1 (``s1``) used for the describe timings.
        window: the map's window mode.
    """

    shortlist: np.ndarray
    frames: np.ndarray
    centres: np.ndarray
    raw: torch.Tensor
    stream: np.ndarray
    truth: GroundTruth
    frame_truth: GroundTruth
    models: dict[str, SeqNet]
    window: str = "centred"

    def __len__(self) -> int:
        return len(self.shortlist)

    def starts(self, length: int) -> np.ndarray:
        """``[Q]`` starts in ``frames`` of the queries' windows of ``length`` (clipped into ``frames``)."""
        return np.clip(self.centres - window_offset(length, self.window), 0, len(self.frames) - length)


def synthetic_queries(conf: TimingConfig, mp: Map, folder: Path) -> Queries:
    """The queries :func:`.synth.write_queries` saved for the map ``mp``."""
    arr = {n: read_npy(folder / f"{n}.npy", False) for n in ("windows", "shortlist", "centres", "stream")}
    q, w, dim = arr["windows"].shape
    frames = arr["windows"].reshape(q * w, dim)
    centres = np.arange(q) * w + w // 2
    off = w // 2 - conf.seq_len // 2
    raw = torch.from_numpy(np.ascontiguousarray(arr["windows"][:, off : off + conf.seq_len]))
    pos = arr["centres"].astype(np.float64)[:, None]
    return Queries(arr["shortlist"], frames, centres, raw, arr["stream"],
                   GroundTruth(pos, mp.positions[mp.items], RADIUS), GroundTruth(pos, mp.positions, RADIUS),
                   random_models(dim, conf.seq_len, conf.sl_w, conf.seed))


def dataset_queries(conf: TimingConfig, mp: Map, dataset: str | Path) -> Queries:
    """``conf.queries`` items (evenly spaced) of the query split the map was built for, described by its models."""
    q = load_query(dataset, mp.config.split)
    mp.check_query(q.traverse.dim, q.traverse.provenance)
    qd = mp.describe(q.traverse)
    pick = np.linspace(0, len(qd.side.items) - 1, min(conf.queries, len(qd.side.items))).round().astype(int)
    items = qd.side.items[pick]
    raw = torch.from_numpy(np.ascontiguousarray(q.traverse.descriptors[window_frames(qd.side.starts[pick],
                                                                                       mp.config.windows.seq_len)]))
    pos, radius = q.traverse.positions[items], q.radius
    models = {r: mp.models[r] for r in ("seqnet", "s1") if r in mp.models}
    frames = qd.frames(mp.config.frames_descriptor)
    stream = frames[: conf.queries + conf.window + conf.warmup].numpy()
    return Queries(qd.items(mp.config.shortlist)[pick].numpy(), frames.numpy(), items, raw.float(), stream,
                   GroundTruth(pos, mp.positions[mp.items], radius), GroundTruth(pos, mp.positions, radius), models,
                   mp.config.window)
