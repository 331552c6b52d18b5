"""A map searched by a single-frame method (``single``, ``s1``): every reference frame, as on a dataset.

A map's items are the frames whose windows fit (a causal map of L = 5 has no item at the first 4 frames of each
sequence, nor in a sequence shorter than L). A single-frame method needs no window: it searches every reference
frame, as ``seqnet eval`` and ``seqnet localize --dataset`` do. The frames without an item (the "edges") are
searched exactly beside the items (through the map's index, or exactly), and the two rankings merged by distance.
Their shortlist descriptors are the map's stored frames when those are the shortlist descriptor (``--shortlist
single --rerank raw+...``, ``--shortlist s1 --rerank s1+...``), else ``edge_shortlist.npy``, written by
:func:`seqnet.maps.build` for that case.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..core.memmaps import take_rows
from ..core.tensors import ArrayLike

Search = Callable[[int], tuple[np.ndarray, np.ndarray]]  # k -> (distances [M, k'], ids [M, k'], -1: none)

EDGE_FILE = "edge_shortlist.npy"


def edge_frames(items: np.ndarray, n_frames: int) -> np.ndarray:
    """``[E]`` the frames of ``0..n_frames-1`` that are no item (``items [R]``), ascending."""
    return np.setdiff1d(np.arange(n_frames, dtype=np.int64), np.asarray(items, dtype=np.int64))


def edge_rows(frames: ArrayLike, edges: np.ndarray) -> np.ndarray:
    """``[E, D]`` the rows ``edges`` of the frame descriptors ``frames [Nr, D]`` (a tensor, array or memory map)."""
    if hasattr(frames, "cpu"):
        return frames[edges].cpu().numpy()
    return take_rows(frames, edges) if len(edges) else np.zeros((0, frames.shape[1]), dtype=np.float32)


def search_every_frame(items: np.ndarray, edges: np.ndarray, by_item: Search, by_edge: Search | None,
                       k: int) -> tuple[np.ndarray, np.ndarray]:
    """``(distances [M, k'], frames [M, k'])`` of the k nearest frames, best first (ties by the lower frame): the
    items' search ``by_item`` (ids into ``items [R]``) merged with the edges' ``by_edge`` (ids into ``edges [E]``;
    None when there are none). ``-1`` where fewer than k were found."""
    d, i = (np.asarray(x) for x in by_item(k))
    dist, frames = [np.where(i >= 0, d, np.inf)], [np.where(i >= 0, items[np.maximum(i, 0)], -1)]
    if by_edge is not None and len(edges):
        d, i = (np.asarray(x) for x in by_edge(k))
        dist.append(np.where(i >= 0, d, np.inf))
        frames.append(np.where(i >= 0, edges[np.maximum(i, 0)], -1))
    d, f = np.concatenate(dist, axis=1), np.concatenate(frames, axis=1)
    order = np.lexsort((np.where(f < 0, np.iinfo(np.int64).max, f), d), axis=-1)[:, :k]
    d, f = np.take_along_axis(d, order, axis=1), np.take_along_axis(f, order, axis=1)
    return d.astype(np.float32, copy=False), f.astype(np.int64, copy=False)
