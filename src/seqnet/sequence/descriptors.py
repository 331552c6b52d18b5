"""Sequence descriptors: smoothing, Delta descriptors and the SeqNet temporal-convolution model (in :mod:`.model`).

Each turns a window of L single-image descriptors ``[M, L, D]`` into one L2-normalised descriptor
``[M, D']``:

* :func:`smoothing` — mean of the (L2-normalised) frames of the window;
* :func:`delta` — seqnet's symmetric Delta descriptor (Garg et al. 2020): mean of the second half of
  the window minus mean of the first half (halves of ``L // 2`` L2-normalised frames; the middle
  frame of an odd window is unused);
* :func:`delta_paper` — ``delta-paper``, the Delta of the SeqNet paper's tables: the original SeqNet
  code's weighting, raw frames weighted ``±1 / (L/2)``, the first ``L // 2`` negative (for odd L the
  middle frame counts in the second half: ``(−0.4, −0.4, +0.4, +0.4, +0.4)`` for L = 5). Its earlier
  name ``delta-orig`` is read as ``delta-paper`` (:data:`DESCRIPTOR_ALIASES`);
* :class:`seqnet.sequence.model.SeqNet` — SeqNet S_L (Garg & Milford 2021): Conv1d over time (D → D_out,
  kernel w, bias, no padding, stride 1), mean over the ``L - w + 1`` outputs, L2 norm. ``S_1`` is ``L = w = 1``.

:data:`SEQUENCE_DESCRIPTORS` names them (plus ``single`` and ``s1``, the descriptors of a window's
own frame); evaluation methods, shortlisters and frame features are built from this table.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.errors import ConfigError
from ..core.lazy import lazy_module, no_grad
from ..core.memmaps import RowsOut, take_rows
from ..core.memory import BLOCK_BYTES as MEMORY_BLOCK
from ..core.progress import progress as progress_bar
from ..core.tensors import ArrayLike, as_tensor, l2_normalize
from .windows import gather_windows

torch = lazy_module("torch")

if TYPE_CHECKING:
    from .model import SeqNet


def smoothing(windows: ArrayLike) -> ArrayLike:
    """Window average: ``[M, L, D]`` → L2-normalised ``[M, D]`` (numpy in, numpy out; one window ``[L, D]`` is
    refused: pass ``x[None]``)."""
    w, numpy_in = window_batch(windows, "smoothing")
    return like_input(l2_normalize(l2_normalize(w).mean(dim=1)), numpy_in)


def delta(windows: ArrayLike) -> ArrayLike:
    """Delta descriptor: ``[M, L, D]`` (L ≥ 2) → L2-normalised ``[M, D]`` (numpy in, numpy out; one window
    ``[L, D]`` is refused: pass ``x[None]``)."""
    windows, numpy_in = window_batch(windows, "delta")
    seq_len = windows.shape[1]
    if seq_len < 2:
        raise ConfigError(f"Delta descriptors need seq_len >= 2, got {seq_len}")
    h = seq_len // 2
    w = l2_normalize(windows)
    return like_input(l2_normalize(w[:, seq_len - h :].mean(dim=1) - w[:, :h].mean(dim=1)), numpy_in)


def delta_paper(windows: ArrayLike) -> ArrayLike:
    """The paper's Delta baseline (the original SeqNet code's): ``[M, L, D]`` (L ≥ 2) → L2-normalised
    ``Σ_t w_t x_t`` with ``w = ±1 / (L/2)``, the first ``L // 2`` frames negative, on raw (not normalised)
    frames."""
    windows, numpy_in = window_batch(windows, "delta_paper")
    seq_len = windows.shape[1]
    if seq_len < 2:
        raise ConfigError(f"Delta descriptors need seq_len >= 2, got {seq_len}")
    weight = torch.full((seq_len,), 2.0 / seq_len, dtype=windows.dtype, device=windows.device)
    weight[: seq_len // 2] *= -1
    return like_input(l2_normalize(torch.einsum("mld,l->md", windows, weight)), numpy_in)


def window_batch(windows: ArrayLike, what: str) -> tuple[torch.Tensor, bool]:
    """``(windows as a float tensor [M, L, D], whether they came as numpy)``; any other number of axes is a
    :class:`ConfigError` (a single window ``[L, D]`` would be read as L windows of one-dimensional frames)."""
    numpy_in = not isinstance(windows, torch.Tensor)
    t = as_tensor(windows, name=f"{what} windows", keep_float64=True) if numpy_in else windows
    if t.ndim != 3:
        hint = "; one window of L frames? add a leading axis (x[None])" if t.ndim == 2 else ""
        raise ConfigError(f"{what}: windows must be [M, L, D] (M windows of L frames of D values), got shape "
                          f"{tuple(t.shape)}{hint}")
    return t, numpy_in


def like_input(x: torch.Tensor, numpy_in: bool) -> ArrayLike:
    """``x`` back in the input's kind: numpy when the windows came as numpy (``numpy_in``), else the tensor."""
    return x.detach().cpu().numpy() if numpy_in else x


def first_frame(windows: torch.Tensor) -> torch.Tensor:
    """The (L2-normalised) descriptor of the window's first frame: ``[M, L, D]`` → ``[M, D]``."""
    return l2_normalize(windows[:, 0])


WINDOW_BYTES = MEMORY_BLOCK // 2  # gathered windows per batch ([B, L, D] float32)


def describe_windows(
    desc: np.ndarray | torch.Tensor,
    idx: np.ndarray,
    fn: Callable[[torch.Tensor], torch.Tensor],
    batch_size: int = 4096,
    device: torch.device | str | None = None,
    progress: str | None = None,
    spill: bool = False,
) -> torch.Tensor | np.ndarray:
    """Apply a window function to every window, in batches of bounded memory.

    Args:
        desc: ``[N, D]`` single-image descriptors (a memory map is read batch by batch, never whole).
        idx: ``[M, L]`` frame indices of the windows (see :func:`seqnet.sequence.windows.window_indices`).
        fn: ``[B, L, D]`` → ``[B, D']`` (``smoothing``, ``delta`` or a :class:`SeqNet`).
        batch_size: at most this many windows per batch (fewer when ``[B, L, D]`` passes 64 MiB).
        device: where to compute (default: where ``desc`` is).
        progress: tqdm label, or None for no bar.
        spill: an output over :data:`seqnet.core.memmaps.SPILL_BYTES` goes to a temporary file.

    Returns:
        ``[M, D']`` float32: a CPU tensor, or a read-only :class:`seqnet.core.memmaps.Spilled` map.
    """
    idx = np.asarray(idx)
    if idx.ndim != 2:
        raise ConfigError(f"window indices must be [M, L], got shape {idx.shape}")
    if len(idx) == 1 and isinstance(desc, torch.Tensor):  # one window in memory (a stream's newest frame)
        return _one_window(as_tensor(desc), idx[0], fn, device)
    per = max(16, WINDOW_BYTES // max(1, idx.shape[1] * desc.shape[1] * 4))
    starts = range(0, len(idx), max(1, min(batch_size, per)))
    out: _Output | None = None
    for s in progress_bar(starts, desc=progress) if progress and len(starts) > 1 else starts:
        block = np.asarray(idx[s : s + starts.step])
        with torch.no_grad():
            y = fn(gather_windows(*_window_rows(desc, block, device))).float().cpu()
        out = out or _Output(len(idx), y.shape[1], spill)
        out.put(y)
    if out is None:  # no windows: still run fn (on an empty batch) for its output width and checks
        empty = as_tensor(desc[:0]).new_zeros((0, idx.shape[1], desc.shape[1]))
        with torch.no_grad():
            return fn(empty.to(device) if device is not None else empty).float().cpu()
    return out.finish()


def _window_rows(desc: np.ndarray | torch.Tensor, block: np.ndarray,
                 device: torch.device | str | None) -> tuple[torch.Tensor, np.ndarray]:
    """``(rows, local)``: the frames the windows ``block [B, L]`` read, each once, and the windows' indices
    into them (a tensor in memory is used whole)."""
    if isinstance(desc, torch.Tensor):
        d = as_tensor(desc)
        return (d.to(device) if device is not None else d), block
    rows = np.unique(block)
    sub = as_tensor(take_rows(desc, rows))
    return (sub.to(device) if device is not None else sub), np.searchsorted(rows, block)


class _Output:
    """``[M, D']`` filled batch by batch (:class:`~seqnet.core.memmaps.RowsOut`): a CPU tensor, or a spill file
    when large."""

    def __init__(self, m: int, dim: int, spill: bool) -> None:
        self.rows = RowsOut((m, dim), np.float32, spill)

    def put(self, y: torch.Tensor) -> None:
        self.rows.put(y.numpy())

    def finish(self) -> torch.Tensor | np.ndarray:
        out = self.rows.finish()
        return out if self.rows.writer is not None else torch.from_numpy(out)


@no_grad
def _one_window(desc: torch.Tensor, frames: np.ndarray, fn: Callable[[torch.Tensor], torch.Tensor],
                device: torch.device | str | None) -> torch.Tensor:
    """``[1, D']``: ``fn`` of the window at the frame indices ``frames [L]`` (a view when they are a run)."""
    run = bool((np.diff(frames) == 1).all())  # consecutive frames: a view of them, no gather
    window = desc[int(frames[0]) : int(frames[-1]) + 1] if run else desc[torch.from_numpy(np.ascontiguousarray(frames))]
    return fn(window[None].to(device) if device is not None else window[None]).float().cpu()


MODEL_ROLES = ("seqnet", "s1")


@dataclasses.dataclass(frozen=True)
class SequenceDescriptor:
    """One entry of :data:`SEQUENCE_DESCRIPTORS`: how a window of frames becomes one descriptor.

    Attributes:
        name: the table key (also the evaluation method that retrieves with it by k-NN).
        summary: one line for ``--help`` and the docs.
        fn: window function ``[M, L, D]`` → ``[M, D']``; None for a model's (see ``model``).
        model: role of the trained model it needs (``"seqnet"``: S_L, ``"s1"``: S_1), or None.
        single_frame: describes only the window's own frame (windows of length 1).
        min_len: the shortest window it accepts.
    """

    name: str
    summary: str
    fn: Callable[[torch.Tensor], torch.Tensor] | None = None
    model: str | None = None
    single_frame: bool = False
    min_len: int = 1

    def window_fn(self, models: Mapping[str, SeqNet]) -> Callable[[torch.Tensor], torch.Tensor]:
        """The window function, with the model taken from ``models`` by role."""
        if self.model is None:
            assert self.fn is not None
            return self.fn
        if self.model not in models:
            raise ConfigError(f"{self.name!r} needs a trained {'S_1' if self.model == 's1' else 'S_L'} model "
                              f"({'--rerank-model' if self.model == 's1' else '--shortlist-model'} CKPT)")
        return models[self.model]

    def length(self, seq_len: int) -> int:
        """Window length used for a sequence length L (1 for single-frame descriptors)."""
        return 1 if self.single_frame else seq_len


SEQUENCE_DESCRIPTORS: dict[str, SequenceDescriptor] = {
    d.name: d
    for d in (
        SequenceDescriptor("single", "the frame's own single-image descriptor", first_frame, single_frame=True),
        SequenceDescriptor("s1", "SeqNet S_1: a learned linear map of the frame's descriptor", model="s1",
                           single_frame=True),
        SequenceDescriptor("smoothing", "mean of the window's L2-normalised descriptors", smoothing),
        SequenceDescriptor("delta", "Delta, symmetric: mean of the window's second half minus its first half "
                           "(middle frame of an odd window unused)", delta, min_len=2),
        SequenceDescriptor("delta-paper", "Delta of the paper's tables: the original SeqNet code's ±2/L weights "
                           "on raw frames", delta_paper, min_len=2),
        SequenceDescriptor("seqnet", "SeqNet S_L: temporal convolution over the window, mean, L2", model="seqnet"),
    )
}

# earlier names, read as their descriptor wherever a name is parsed (methods, maps, CLI choices); outputs carry the key
DESCRIPTOR_ALIASES: dict[str, str] = {"delta-orig": "delta-paper"}


def descriptor_name(name: str) -> str:
    """The key of :data:`SEQUENCE_DESCRIPTORS` that ``name`` means (itself, or an alias's descriptor)."""
    return DESCRIPTOR_ALIASES.get(name, name)


def __getattr__(name: str) -> Any:  # PEP 562: names that lived here before (outside scripts keep working)
    if name == "SeqNet":
        from .model import SeqNet  # the model class: torch loads here

        return SeqNet
    if name == "delta_orig":
        return delta_paper
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
