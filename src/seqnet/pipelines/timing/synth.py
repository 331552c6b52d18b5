"""Synthetic maps with structure for the timing benchmark, and the queries timed against them.

The route is a smooth AR(1) walk ``z[t] = ρ z[t−1] + √(1−ρ²) ε`` in D dimensions (ρ = 0.9: frames a
step apart are similar, frames far apart are not); the map's frame descriptors are ``z / ‖z‖``
and its shortlist descriptor of an item is the L2-normalised mean of its L-frame window (the
``smoothing`` descriptor). A query is the same stretch of the route seen again with per-frame
noise (``noise`` relative to the signal); it is correct within ``RADIUS`` frames.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch

from ...core.provenance import make as make_provenance
from ...maps import MapArrays, MapConfig, write_map
from ...security.files import save_npy_atomic
from ...sequence.model import SeqNet
from .config import TimingConfig

RHO = 0.9
RADIUS = 2.0
CHUNK_ELEMENTS = 2**24  # values generated per chunk (memory-bounded for any N_db and D)


def _unit(x: np.ndarray) -> np.ndarray:
    return (x / np.linalg.norm(x, axis=-1, keepdims=True)).astype(np.float32)


def route(n: int, dim: int, rng: np.random.Generator) -> np.ndarray:
    """``[n, dim]`` float32 unit frame descriptors of an AR(1) route, generated in chunks."""
    from scipy.signal import lfilter

    out = np.empty((n, dim), np.float32)
    state = RHO * rng.standard_normal((1, dim))  # a stationary start; the filter state carries the walk on
    chunk = max(1, CHUNK_ELEMENTS // dim)
    for a in range(0, n, chunk):
        eps = rng.standard_normal((min(n, a + chunk) - a, dim))
        z, state = lfilter([np.sqrt(1 - RHO**2)], [1.0, -RHO], eps, axis=0, zi=state)
        out[a : a + len(z)] = _unit(z)
    return out


def window_means(frames: np.ndarray, starts: np.ndarray, length: int) -> np.ndarray:
    """``[M, D]`` L2-normalised means of the windows ``frames[s : s + length]`` (the smoothing descriptor)."""
    out = np.empty((len(starts), frames.shape[1]), np.float32)
    chunk = max(1, CHUNK_ELEMENTS // frames.shape[1])
    for a in range(0, len(starts), chunk):
        s = starts[a : a + chunk]
        acc = np.zeros((len(s), frames.shape[1]), np.float64)
        for t in range(length):
            acc += frames[s + t]
        out[a : a + len(s)] = _unit(acc)
    return out


@dataclasses.dataclass
class Layout:
    """Where the items and query windows of a synthetic map lie (``window`` = longest L / L_m)."""

    n: int
    window: int

    @property
    def items(self) -> np.ndarray:
        """Frames whose every window (length <= ``window``, centred) fits inside the route."""
        return np.arange(self.window // 2, self.n - self.window + self.window // 2 + 1)

    def starts(self, length: int, centres: np.ndarray) -> np.ndarray:
        """Starts of the centred windows of ``length`` around ``centres``."""
        return np.asarray(centres) - length // 2


def make_map(conf: TimingConfig, n: int, dim: int, out: Path) -> Path:
    """Write a synthetic map of ``n`` frames of D = ``dim`` to ``out`` and its queries to ``out.parent``."""
    rng = np.random.default_rng([conf.seed, n, dim])
    frames = route(n, dim, rng)
    lay = Layout(n, conf.window)
    items = lay.items
    shortlist = window_means(frames, lay.starts(conf.seq_len, items), conf.seq_len)
    mconf = MapConfig(shortlist="smoothing", rerank="raw+seqmatch", seq_len=conf.seq_len,
                      match_len=max(conf.seq_lens), ann=conf.ann.merge(kind="flat"), dtype=conf.dtype)
    arrays = MapArrays(shortlist, frames, items, lay.starts(max(conf.seq_lens), items),
                       np.arange(n, dtype=np.float64)[:, None])
    prov = make_provenance("synthetic", {"generator": "timing-route", "rho": RHO, "seed": conf.seed}, dim=dim)
    write_map(out, mconf, arrays, provenance=prov, info={"synthetic": True, "input_dim": dim})
    write_queries(conf, frames, lay, rng, out.parent / f"queries-{n}-{dim}")
    return out


def write_queries(conf: TimingConfig, frames: np.ndarray, lay: Layout, rng: np.random.Generator, out: Path) -> None:
    """Query windows (``[Q, window, D]`` frames, their shortlist descriptors and centres) and a
    contiguous query stream for the online / batch matchers, saved as ``.npy`` files in ``out``."""
    q, w, dim = conf.queries, conf.window, frames.shape[1]
    centres = rng.choice(lay.items, size=q, replace=len(lay.items) < q)
    idx = lay.starts(w, centres)[:, None] + np.arange(w)
    scale = np.sqrt(dim)  # a unit frame times √D has unit-variance coordinates, like the noise
    windows = _unit(frames[idx] * scale + conf.noise * rng.standard_normal((q, w, dim)))
    off = w // 2 - conf.seq_len // 2
    shortlist = _unit(windows[:, off : off + conf.seq_len].mean(axis=1))
    length = min(lay.n, q + w + conf.warmup)  # frames fed to the online matcher
    s0 = int(rng.integers(0, lay.n - length + 1))
    stream = _unit(frames[s0 : s0 + length] * scale + conf.noise * rng.standard_normal((length, dim)))
    out.mkdir(parents=True, exist_ok=True)
    for name, arr in (("windows", windows), ("shortlist", shortlist), ("centres", centres.astype(np.int64)),
                      ("stream", stream), ("stream_start", np.array([s0], np.int64))):
        save_npy_atomic(out / f"{name}.npy", arr)


def random_models(dim: int, seq_len: int, w: int, seed: int) -> dict[str, SeqNet]:
    """Randomly initialised S_L (``D → D``, L, w) and S_1 (``D → D``) of the paper's size, for describe timings."""
    torch.manual_seed(seed)
    return {"seqnet": SeqNet(dim, dim, seq_len, w).eval(), "s1": SeqNet(dim, dim, 1, 1).eval()}
