"""Sequence windows over a traverse.

A window of length L for frame i is a run of L consecutive frames:

* ``centred`` (the paper's evaluation): frames ``i - L//2 ... i - L//2 + L - 1``;
* ``causal`` (online use): frames ``i - L + 1 ... i``.

A window never crosses a sequence bound (``seq_bounds[i] = [start, end)``, or the whole traverse
when there are none). Frames whose window does not fit are *invalid*: they are left out of
evaluation, and the number left out is reported.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from ..core.config import check_float
from ..core.errors import ConfigError, WindowsTooLongError
from ..core.lazy import lazy_module

torch = lazy_module("torch")

WINDOW_MODES = ("centred", "causal")


def check_seq_len(seq_len: int, n: int | None = None, what: str = "seq_len") -> int:
    """Validate a sequence length (an int ≥ 1, and ≤ n when n is given)."""
    if isinstance(seq_len, bool) or not isinstance(seq_len, (int, np.integer)) or seq_len < 1:
        raise ConfigError(f"{what} must be an integer >= 1, got {seq_len!r}")
    if n is not None and seq_len > n:
        raise WindowsTooLongError(f"{what}={seq_len} is longer than the traverse ({n} frames)")
    return int(seq_len)


def window_offset(seq_len: int, mode: str = "centred") -> int:
    """Offset of the window start from its frame: ``start = i - offset``."""
    if mode not in WINDOW_MODES:
        raise ConfigError(f"window mode {mode!r} is not one of {WINDOW_MODES}")
    return seq_len // 2 if mode == "centred" else seq_len - 1


def frame_bounds(n: int, seq_bounds: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """``(starts [n], ends [n])``: the half-open sequence of each of ``n`` frames (all of them without bounds)."""
    if seq_bounds is None:
        return np.zeros(n, dtype=np.int64), np.full(n, n, dtype=np.int64)
    b = np.asarray(seq_bounds, dtype=np.int64)
    if b.shape != (n, 2):
        raise ConfigError(f"seq_bounds must be [{n}, 2] (one [start, end) row per frame), got shape {b.shape}")
    return b[:, 0], b[:, 1]


def window_starts(
    n: int, seq_len: int, mode: str = "centred", seq_bounds: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Window start of every frame and whether the full window fits.

    Args:
        n: number of frames N.
        seq_len: window length L (≥ 1).
        mode: ``"centred"`` or ``"causal"``.
        seq_bounds: optional ``[N, 2]`` half-open sequence range per frame.

    Returns:
        ``(starts [N] int64, valid [N] bool)``; ``starts`` may be out of range where not valid.
    """
    check_seq_len(seq_len)
    if n < 0:
        raise ConfigError(f"number of frames must be >= 0, got {n}")
    starts = np.arange(n, dtype=np.int64) - window_offset(seq_len, mode)
    lo, hi = frame_bounds(n, seq_bounds)
    valid = (starts >= lo) & (starts + seq_len <= hi)
    return starts, valid


def window_indices(
    n: int, seq_len: int, mode: str = "centred", seq_bounds: np.ndarray | None = None
) -> np.ndarray:
    """Frame indices ``[N, L]`` of every frame's window, clamped into its sequence.

    Where the full window does not fit, out-of-sequence positions repeat the nearest frame of the
    sequence (replicate padding), so every frame gets a window of length L.
    """
    if seq_bounds is None and n <= 64:  # a short run of one sequence (the localiser's recent frames): kept
        return _one_sequence(n, seq_len, mode).copy()
    starts, _ = window_starts(n, seq_len, mode, seq_bounds)
    lo, hi = frame_bounds(n, seq_bounds)
    return np.clip(window_frames(starts, seq_len), lo[:, None], hi[:, None] - 1)


@functools.lru_cache(maxsize=256)
def _one_sequence(n: int, seq_len: int, mode: str) -> np.ndarray:
    starts, _ = window_starts(n, seq_len, mode, None)
    out = np.clip(window_frames(starts, seq_len), 0, n - 1)
    out.flags.writeable = False  # shared between callers
    return out


def window_frames(starts: np.ndarray, seq_len: int) -> np.ndarray:
    """Frame indices ``[M, L]`` of the windows that start at ``starts [M]``: ``starts[m] + t``."""
    return np.asarray(starts, dtype=np.int64)[:, None] + np.arange(seq_len, dtype=np.int64)[None, :]


def check_speed_range(name: str, speed: object) -> tuple[float, float]:
    """``(A, B)`` with ``0 < A <= B`` (finite) of a speed range (training re-sampling, a query's speeds);
    lists are read as pairs."""
    if isinstance(speed, (str, bytes)) or not hasattr(speed, "__len__") or len(speed) != 2:
        raise ConfigError(f"{name} must be two numbers A:B with 0 < A <= B (e.g. 0.5:2), got {speed!r}")
    lo, hi = (check_float(name, v, 0.0, strict=True) for v in speed)
    if lo > hi:
        raise ConfigError(f"{name} A:B needs A <= B, got {lo:g}:{hi:g} (hint: e.g. 0.5:2)")
    return lo, hi


def speed_windows(items: np.ndarray, seq_len: int, mode: str, speeds: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """Frames ``[M, L]`` of the windows of frames ``items [M]`` re-sampled at ``speeds [M]`` (frames per step).

    With ``a = window_offset(L, mode)``: ``start = i − round(a·v)`` and frame ``t`` of the window is
    ``start + round(t·v)`` (round half up), so step ``a`` is frame ``i`` itself and ``v = 1`` gives the
    usual window. A re-sampled window that would leave its sequence (``bounds [M, 2]``, half-open) is
    the usual one.
    """
    items, v = np.asarray(items, dtype=np.int64), np.asarray(speeds, dtype=np.float64)
    a, t = window_offset(seq_len, mode), np.arange(seq_len, dtype=np.float64)
    frames = (items - np.floor(a * v + 0.5).astype(np.int64))[:, None] + np.floor(t[None, :] * v[:, None] + 0.5)
    frames = frames.astype(np.int64)
    b = np.asarray(bounds, dtype=np.int64)
    fits = (frames.min(axis=1) >= b[:, 0]) & (frames.max(axis=1) < b[:, 1])
    usual = window_frames(items - a, seq_len)
    return np.where(fits[:, None], frames, usual)


def gather_windows(desc: torch.Tensor, idx: np.ndarray | torch.Tensor) -> torch.Tensor:
    """Stack windows: ``desc [N, D]``, ``idx [M, L]`` → ``[M, L, D]``."""
    idx_t = torch.as_tensor(idx, dtype=torch.long, device=desc.device)
    return desc[idx_t.reshape(-1)].reshape(*idx_t.shape, desc.shape[-1])


DEFAULT_SEQ_LEN = 5  # L when neither the settings nor an S_L model give one
MODE_ANCHORS = {"centred": "centre", "causal": "end"}  # the window step pinned to the item's own frame


@dataclasses.dataclass(frozen=True)
class Windows:
    """The windows of one evaluation, map or localiser, resolved once.

    Attributes:
        seq_len: L, the window of the sequence descriptors.
        match_len: L_m, the window of the sequence matchers.
        mode: ``"centred"`` (the paper's) or ``"causal"`` (online).
        anchor: the step of an L_m-window pinned to the item's frame by the anchored (variable-speed)
            matchers: ``"centre"`` for centred windows, ``"end"`` (the newest frame) for causal ones.
    """

    seq_len: int
    match_len: int
    mode: str = "centred"
    anchor: str = ""

    def __post_init__(self) -> None:
        check_seq_len(self.seq_len, None, "seq_len")
        check_seq_len(self.match_len, None, "match_len")
        window_offset(1, self.mode)  # validates the mode
        if not self.anchor:
            object.__setattr__(self, "anchor", MODE_ANCHORS[self.mode])

    @classmethod
    def resolve(cls, seq_len: int | None, match_len: int | None, mode: str = "centred",
                model_len: int | None = None, anchor: str = "") -> Windows:
        """L (given, else the S_L model's ``model_len``, else :data:`DEFAULT_SEQ_LEN`) and L_m (given, else L)."""
        seq_len = seq_len or model_len or DEFAULT_SEQ_LEN
        return cls(seq_len, match_len or seq_len, mode, anchor)

    @property
    def longest(self) -> int:
        """max(L, L_m): the frames an item's windows span."""
        return max(self.seq_len, self.match_len)

    @property
    def longest_option(self) -> str:
        """The option that sets the longer window (what to shorten when it does not fit)."""
        return longest_option(self.seq_len, self.match_len)

    def side(self, t_len: int, seq_bounds: np.ndarray | None) -> Side:
        """The items of a traverse of ``t_len`` frames: frames whose L- and L_m-windows fit inside their sequence."""
        starts, ok = window_starts(t_len, self.seq_len, self.mode, seq_bounds)
        m_starts, m_ok = window_starts(t_len, self.match_len, self.mode, seq_bounds)
        items = np.flatnonzero(ok & m_ok)
        return Side(items, starts[items], m_starts[items])


def longest_option(seq_len: int, match_len: int) -> str:
    """``--match-len`` when L_m > L, else ``--seq-len``: the option that sets the longest window."""
    return "--match-len" if match_len > seq_len else "--seq-len"


@dataclasses.dataclass(frozen=True)
class Side:
    """The items of one traverse under :class:`Windows`.

    Attributes:
        items: ``[M]`` frame index of each item (the frame whose windows fit).
        starts: ``[M]`` first frame of each item's L-frame descriptor window.
        match_starts: ``[M]`` first frame of each item's L_m-frame matching window.
    """

    items: np.ndarray
    starts: np.ndarray
    match_starts: np.ndarray


class WindowedItems:
    """Base of the described sides (:class:`seqnet.sequence.described.Described`, its numpy counterpart
    :class:`seqnet.sequence.npdescribed.PlainDescribed`): the items of ``n`` frames under ``windows``."""

    side: Side
    seq_bounds: np.ndarray | None

    def _set_side(self, windows: Windows, n: int, seq_bounds: np.ndarray | None, what: str) -> None:
        """:attr:`side` of ``n`` frames (``seq_bounds [n, 2]`` or None, kept as :attr:`seq_bounds`);
        :class:`ConfigError` when no item fits."""
        self.side, self.seq_bounds = windows.side(n, seq_bounds), seq_bounds
        if len(self.side.items) == 0:
            raise ConfigError(f"no {what} frame has a full window of seq_len={windows.seq_len} (L_m="
                              f"{windows.match_len}) inside its sequence; use a shorter {windows.longest_option}")

    @property
    def items_index(self) -> np.ndarray:
        """``[M]`` frame of each item."""
        return self.side.items

    @property
    def match_starts(self) -> np.ndarray:
        """``[M]`` first frame of each item's L_m-window."""
        return self.side.match_starts


class WindowSettings:
    """Mixin of the configs that carry ``seq_len`` (L), ``match_len`` (L_m) and ``window`` fields, as given
    (None: the default); :attr:`windows` resolves them one way everywhere (L: :data:`DEFAULT_SEQ_LEN`, L_m: L)."""

    seq_len: int | None
    match_len: int | None
    window: str
    RENAMED_KEYS: ClassVar[Mapping[str, str]] = {"rerank_seq_len": "match_len"}  # configs written before 0.3

    @property
    def windows(self) -> Windows:
        """The :class:`Windows` of these settings (L, L_m resolved; the mode)."""
        return Windows.resolve(self.seq_len, self.match_len, self.window)
