"""The model-free sequence descriptors in numpy, and a traverse described with them: :class:`PlainDescribed`.

``single``, ``smoothing``, ``delta`` and ``delta-paper`` need no model: their window functions
(:data:`PLAIN_DESCRIPTORS`) are those of :mod:`seqnet.sequence.descriptors` written on numpy arrays, so that
evaluating them (:mod:`seqnet.reference.plain`) never loads torch. Each computes in its input's float dtype
(float64 stays float64, anything else is float32) and returns float32, as the torch functions do; the
values agree with them to float rounding (``tests/sequence/test_npdescribed.py``).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from ..core.errors import ConfigError
from ..core.memmaps import RowsOut, read_rows, take_rows
from ..core.memory import BLOCK_BYTES
from .windows import WindowedItems, Windows, window_frames


def l2_normalize_np(x: np.ndarray, out: np.ndarray | None = None, eps: float = 1e-12) -> np.ndarray:
    """:func:`seqnet.core.tensors.l2_normalize` in numpy, along the last axis: rows divided by their largest
    magnitude, then by their norm (at least ``eps``; zero rows stay zero), into ``out`` when given (e.g. float32
    rows of a float64 ``x``); no other full-size temporary."""
    x = x if x.dtype.kind == "f" else x.astype(np.float32)
    scale = np.maximum(np.maximum(x.max(axis=-1), -x.min(axis=-1)), np.finfo(x.dtype).tiny)
    y = np.divide(x, scale[..., None], out=out, casting="same_kind")
    norm = np.sqrt(np.einsum("...i,...i->...", y, y))
    y /= np.maximum(norm, eps).astype(y.dtype)[..., None]
    return y


def first_frame_np(windows: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``single``: the L2-normalised first frame, ``[M, L, D]`` → ``[M, D]``."""
    return l2_normalize_np(windows[:, 0], out)


def smoothing_np(windows: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``smoothing``: the L2-normalised mean of the L2-normalised frames."""
    return l2_normalize_np(l2_normalize_np(windows).mean(axis=1), out)


def _check_len(windows: np.ndarray) -> int:
    if windows.shape[1] < 2:
        raise ConfigError(f"Delta descriptors need seq_len >= 2, got {windows.shape[1]}")
    return windows.shape[1]


def delta_np(windows: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``delta``: the mean of the second half of the normalised frames minus the mean of the first half."""
    seq_len = _check_len(windows)
    h, w = seq_len // 2, l2_normalize_np(windows)
    return l2_normalize_np(w[:, seq_len - h :].mean(axis=1) - w[:, :h].mean(axis=1), out)


def delta_paper_np(windows: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``delta-paper``: raw frames weighted ``±2 / L`` (the first ``L // 2`` negative), summed, normalised."""
    seq_len = _check_len(windows)
    x = windows if windows.dtype.kind == "f" else windows.astype(np.float32)
    weight = np.full(seq_len, 2.0 / seq_len, dtype=x.dtype)
    weight[: seq_len // 2] *= -1
    return l2_normalize_np(np.einsum("mld,l->md", x, weight), out)


# each: (windows [M, L, D], out [M, D] float32 or None) -> [M, D]
PLAIN_DESCRIPTORS: dict[str, Callable[..., np.ndarray]] = {
    "single": first_frame_np, "smoothing": smoothing_np, "delta": delta_np, "delta-paper": delta_paper_np}


def inverse_norms(raw: np.ndarray, block_bytes: int = BLOCK_BYTES) -> np.ndarray | None:
    """``[N]`` float64 ``1 / ‖row‖`` of ``raw [N, D]`` (0 for a zero row), read in blocks: ``single``'s rows are
    ``raw[i] * inverse_norms(raw)[i]`` (:func:`first_frame_np` to rounding), to search without a normalised copy.
    None when a row's squared norm overflows or underflows its dtype (then describe it: :func:`describe_np`)."""
    x0 = raw[:0]
    dtype = x0.dtype if x0.dtype.kind == "f" else np.dtype(np.float32)
    eps, tiny = np.finfo(dtype).eps, np.finfo(dtype).tiny
    step, out = max(1, block_bytes // max(1, raw.shape[1] * dtype.itemsize)), []
    for a in range(0, len(raw), step):
        x = np.asarray(read_rows(raw, a, a + step), dtype=dtype)
        sq = np.einsum("ij,ij->i", x, x).astype(np.float64)
        big = np.maximum(x.max(axis=1), -x.min(axis=1)).astype(np.float64)
        if not np.isfinite(sq).all() or ((big > 0) & (big * big < tiny / eps)).any():
            return None
        out.append(np.divide(1.0, np.sqrt(sq), out=np.zeros_like(sq), where=sq > 0))
    return np.concatenate(out) if out else np.zeros(0)


def describe_np(raw: np.ndarray, idx: np.ndarray, name: str, spill: bool = False,
                block_bytes: int = BLOCK_BYTES) -> np.ndarray:
    """``[M, D]`` float32: descriptor ``name`` (a key of :data:`PLAIN_DESCRIPTORS`) of the windows ``idx [M, L]``
    of ``raw [N, D]`` (a memory map is read batch by batch), in batches of at most ``block_bytes`` of windows;
    ``spill``: a large result is a temporary memory map (:class:`seqnet.core.memmaps.RowsOut`)."""
    fn, idx = PLAIN_DESCRIPTORS[name], np.asarray(idx, dtype=np.int64)
    step = max(1, block_bytes // max(1, idx.shape[1] * raw.shape[1] * 8))
    out = RowsOut((len(idx), raw.shape[1]), np.float32, spill)
    for s in range(0, len(idx), step):
        block = idx[s : s + step]
        dest = out.slot(len(block))  # computed straight into the result's rows (None: spilled, put after)
        y = fn(_windows(raw, block), np.empty((len(block), raw.shape[1]), np.float32) if dest is None else dest)
        if dest is None:
            out.put(y)
    return out.finish()


def _windows(raw: np.ndarray, block: np.ndarray) -> np.ndarray:
    """``[B, L, D]``: the frames of the windows ``block [B, L]``, each frame read once (a run of frames: a slice,
    a view of an array or a memory map held resident; one frame per window in order: no gather)."""
    frames, local = np.unique(block, return_inverse=True)
    a, b = int(frames[0]), int(frames[-1]) + 1
    rows = read_rows(raw, a, b) if b - a == len(frames) else take_rows(raw, frames)
    if block.shape[1] == 1 and len(frames) == len(block) and bool((frames == block[:, 0]).all()):
        return rows[:, None]
    return rows[local.reshape(block.shape)]


class PlainDescribed(WindowedItems):
    """One traverse's items under ``windows`` and their model-free descriptors (numpy), each computed once and
    timed: the numpy counterpart of :class:`seqnet.sequence.described.Described` for k-NN methods (items only).

    Args:
        descriptors: ``[N, D]`` single-image descriptors (numpy array or memory map).
        seq_bounds: ``[N, 2]`` sequence range of every frame, or None.
        windows: L, L_m and the window mode; what: ``"query"`` or ``"reference"`` (for errors);
        spill: large descriptors go to temporary memory maps (a reference side).
    """

    def __init__(self, descriptors: np.ndarray, seq_bounds: np.ndarray | None, windows: Windows,
                 what: str = "query", spill: bool = False) -> None:
        self.raw, self.windows, self.spill = descriptors, windows, spill
        self._set_side(windows, len(descriptors), seq_bounds, what)
        self._cache: dict[str, np.ndarray] = {}
        self.ms: dict[str, float] = {}

    def items(self, name: str) -> np.ndarray:
        """``[M, D]`` float32 item descriptors ``name`` (an array, or a spilled memory map)."""
        if name not in self._cache:
            t0 = time.perf_counter()
            single = name == "single"
            idx = self.side.items[:, None] if single else window_frames(self.side.starts, self.windows.seq_len)
            self._cache[name] = describe_np(self.raw, idx, name, self.spill)
            self.ms[name] = (time.perf_counter() - t0) * 1e3
        return self._cache[name]

    def frames(self, name: str) -> np.ndarray:
        raise ConfigError(f"frame descriptors ({name!r}) are for the sequence matchers; a model-free k-NN "
                          "evaluation reads item descriptors only")

    def cost_ms(self, keys: list[tuple[str, str]]) -> float:
        """Milliseconds spent on the item descriptors ``keys`` (``("items", name)`` pairs), each once."""
        names = {name for _, name in keys}
        for name in names:
            self.items(name)
        return sum(self.ms[n] for n in names)
