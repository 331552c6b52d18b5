"""The windows a training split gives: every query with a positive and a negative, every reference
window, their positions (and explicit positives), on the compute device (:class:`TripletSource`),
and, with speed augmentation, the query windows re-sampled at random speeds (:func:`speed_source`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..core.errors import DatasetError
from ..core.lazy import lazy_module
from ..core.memmaps import streamed, take_rows
from ..core.tensors import as_tensor
from ..data.positives import Positives
from ..data.spacing import DEGREES_HINT, looks_like_degrees
from ..data.traverse import Dataset, Traverse
from ..sequence.windows import frame_bounds, gather_windows, speed_windows, window_frames, window_starts
from .config import MiningConfig, TrainConfig
from .truth import nonnegative_keys, positive_keys, queries_with_pairs

torch = lazy_module("torch")


@dataclasses.dataclass
class SplitWindows:
    """The windows a split gives to training (frame indices and positions, on the host).

    ``q_idx [M, L]`` frames of the M queries with a positive and a negative; ``r_idx [R, L]`` frames
    of every reference window; ``q_pos [M, P]`` / ``r_pos [R, P]`` positions of the windows' frames;
    ``left_out``: queries with a full window but without a positive or a negative.
    """

    q_idx: np.ndarray
    r_idx: np.ndarray
    q_pos: np.ndarray
    r_pos: np.ndarray
    left_out: int
    positives: Positives | None = None  # explicit positives over (kept query window, reference window)
    q_items: np.ndarray | None = None  # [M] frame of each kept query (its window's anchor)
    q_bounds: np.ndarray | None = None  # [M, 2] the half-open sequence of each kept query


@dataclasses.dataclass
class TripletSource:
    """Training windows on the compute device.

    ``q_desc [Nq, D]`` / ``r_desc [Nr, D]`` frame descriptors (a streamed memory map on the CPU stays one:
    :func:`on_device`); ``q_idx [M, L]`` frames of the M
    training queries (those with a positive and a negative); ``r_idx [R, L]`` frames of every
    reference window; ``q_pos [M, P]`` / ``r_pos [R, P]`` float64 positions of the windows' frames;
    ``left_out``: queries left out (no positive or no negative).
    """

    q_desc: torch.Tensor | np.ndarray
    r_desc: torch.Tensor | np.ndarray
    q_idx: torch.Tensor
    r_idx: torch.Tensor
    q_pos: torch.Tensor
    r_pos: torch.Tensor
    left_out: int = 0
    pos_keys: torch.Tensor | None = None  # explicit positive pairs (train/truth.positive_keys), or None
    soft_keys: torch.Tensor | None = None  # soft positive pairs, never negatives (train/truth.nonnegative_keys)
    q_items: np.ndarray | None = None  # [M] frame of each training query (host; speed augmentation)
    q_bounds: np.ndarray | None = None  # [M, 2] its half-open sequence (host)

    @property
    def n_queries(self) -> int:
        return int(self.q_idx.shape[0])

    @property
    def device(self) -> torch.device:
        """The compute device (where the windows' indices are)."""
        return self.q_idx.device


def on_device(desc: np.ndarray, device: torch.device) -> torch.Tensor | np.ndarray:
    """Frame descriptors ``desc [N, D]`` for training on ``device``: a float32 tensor there, except that a
    streamed memory map (:func:`seqnet.core.memmaps.streamed`) trained on the CPU stays the map (read in
    blocks, never copied whole)."""
    if device.type == "cpu" and streamed(desc):
        return desc
    return as_tensor(desc, device)


def source_windows(desc: torch.Tensor | np.ndarray, idx: torch.Tensor) -> torch.Tensor:
    """``[M, L, D]`` float32 windows of ``desc [N, D]`` (a tensor, or a map from :func:`on_device`) at the
    frames ``idx [M, L]``, on ``idx``'s device."""
    if isinstance(desc, torch.Tensor):
        return gather_windows(desc, idx)
    flat = take_rows(desc, idx.reshape(-1).cpu().numpy())
    return as_tensor(flat, idx.device).reshape(*idx.shape, desc.shape[1])


def sequence_bounds(t: Traverse, items: np.ndarray) -> np.ndarray:
    """``[M, 2]`` the half-open sequence of each frame ``items [M]`` of ``t`` (the traverse without bounds)."""
    return np.stack(frame_bounds(len(t), t.seq_bounds), axis=1)[items]


def _full_windows(t: Traverse, seq_len: int, mode: str, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Frames with a full window inside their sequence ``[M]`` and the windows' frames ``[M, L]``."""
    starts, valid = window_starts(len(t), seq_len, mode, t.seq_bounds)
    items = np.flatnonzero(valid)
    if items.size == 0:
        raise DatasetError(f"{what} split: no {t.name} frame (of {len(t)}) has a full window of seq_len={seq_len} "
                           f"inside its sequence (hint: a longer {what} range or a shorter --seq-len)")
    return items, window_frames(starts[items], seq_len)


def widen_windows(t: Traverse, items: np.ndarray, idx: np.ndarray, pad: int) -> tuple[np.ndarray, np.ndarray]:
    """Windows ``idx [M, L]`` widened by ``pad`` frames on either side (``[M', L + 2·pad]``), keeping only those
    inside their frame's sequence (the velocity-robust loss's reference windows); ``(items [M'], idx)``."""
    if pad == 0:
        return items, idx
    wide = window_frames(idx[:, 0] - pad, idx.shape[1] + 2 * pad)
    lo, hi = frame_bounds(len(t), t.seq_bounds)
    inside = (wide[:, 0] >= lo[items]) & (wide[:, -1] < hi[items])
    return items[inside], wide[inside]


def split_windows(ds: Dataset, seq_len: int, window: str, conf: MiningConfig, what: str = "train",
                  ref_pad: int = 0) -> SplitWindows:
    """The query and reference windows of the split ``ds`` (already split; ``what`` names it in errors);
    ``ref_pad``: reference windows widened by that many frames on either side (:func:`widen_windows`).

    Raises :class:`DatasetError` when a traverse has no full window, or when no query has both a
    positive (a reference within ``conf.pos_radius``, or an explicit one) and a negative (beyond
    ``conf.neg_radius`` of the query, or of all its explicit positives: :func:`~seqnet.train.truth.pair_masks`).
    """
    q_items, q_idx = _full_windows(ds.query, seq_len, window, what)
    r_items, r_idx = widen_windows(ds.reference, *_full_windows(ds.reference, seq_len, window, what), ref_pad)
    if r_items.size == 0:
        raise DatasetError(f"{what} split: no {ds.reference.name} window of {seq_len} + 2·{ref_pad} frames fits inside "
                           f"its sequence (hint: a longer {what} range or a shorter --match-len)")
    q_pos, r_pos = ds.query.positions[q_items], ds.reference.positions[r_items]
    positives = ds.positives.select(q_items, r_items) if ds.positives is not None else None
    keep = queries_with_pairs(q_pos, r_pos, conf.pos_radius, conf.neg_radius, positives)
    if not keep.any():
        degrees = positives is None and looks_like_degrees(np.concatenate([q_pos, r_pos]))
        raise DatasetError(f"{ds.name}: none of {len(q_items)} {'training' if what == 'train' else what} queries has "
                           f"{_pair_words(conf, ds.position_unit, positives is not None, what, degrees)}")
    kept = positives.select(np.flatnonzero(keep), np.arange(len(r_items))) if positives is not None else None
    return SplitWindows(q_idx[keep], r_idx, q_pos[keep], r_pos, int((~keep).sum()), kept, q_items[keep],
                        sequence_bounds(ds.query, q_items[keep]))


def _pair_words(conf: MiningConfig, unit: str, explicit: bool, what: str, degrees: bool = False) -> str:
    """What a query lacks when none has a positive and a negative (the end of the error), by radius or explicit;
    ``degrees``: the positions look like degrees, which no radius in metres fits (said instead of the radius
    hint)."""
    if explicit:
        return (f"a positive and a reference farther than neg_radius={conf.neg_radius:g} {unit} from its positives "
                f"(hint: check the {what} ranges of reference and query, the positives, or a smaller --neg-radius)")
    hint = (f"{DEGREES_HINT}; no radius in metres fits degrees" if degrees else f"hint: check the {what} ranges of "
            "reference and query, or a larger --pos-radius / a smaller --neg-radius")
    return (f"a reference within pos_radius={conf.pos_radius:g} and one beyond neg_radius={conf.neg_radius:g} "
            f"{unit} ({hint})")


def named_split(ds: Dataset, name: str, what: str) -> Dataset:
    """The split ``name`` of ``ds`` (``what``: "train" or "val", the flag the error's hint names)."""
    try:
        return ds.split(name)
    except DatasetError as e:
        hint = " or none to skip validation" if what == "val" else " (all: the whole dataset)"
        raise DatasetError(f"{e} (hint: --{what}-split NAME{hint})") from e


def check_splits(dataset: Dataset, conf: TrainConfig) -> None:
    """The checks of the training data that read no descriptor (:func:`seqnet.train.loop.prepare`'s: the splits
    exist, their windows fit, some training query has a positive and a negative), with ``conf``'s radii resolved
    on ``dataset``: for a caller about to write something first (``seqnet train --pca`` writes the reduced
    dataset: refused runs leave nothing behind)."""
    conf = conf.resolve(dataset)
    split_windows(named_split(dataset, conf.train_split, "train"), conf.window_len, conf.window, conf.mining,
                  "train", conf.ref_pad)
    if conf.validates:
        split_windows(named_split(dataset, conf.val_split, "val"), conf.window_len, conf.window, conf.mining, "val",
                      conf.ref_pad)


def triplet_source(ds: Dataset, seq_len: int, window: str, conf: MiningConfig, device: torch.device,
                   ref_pad: int = 0) -> TripletSource:
    """Windows, positions and descriptors of the training split ``ds`` (already split) on ``device``.

    Raises :class:`DatasetError` as :func:`split_windows`.
    """
    sw = split_windows(ds, seq_len, window, conf, "train", ref_pad)
    as_long = lambda a: torch.as_tensor(a, dtype=torch.long, device=device)  # noqa: E731
    keys = soft = None
    if sw.positives is not None:
        keys, soft = positive_keys(sw.positives, len(sw.r_idx)), nonnegative_keys(sw.positives, len(sw.r_idx))
    return TripletSource(on_device(ds.query.descriptors, device), on_device(ds.reference.descriptors, device),
                         as_long(sw.q_idx), as_long(sw.r_idx), torch.as_tensor(sw.q_pos, device=device),
                         torch.as_tensor(sw.r_pos, device=device), sw.left_out,
                         None if keys is None else keys.to(device), None if soft is None else soft.to(device),
                         sw.q_items, sw.q_bounds)


def draw_speeds(n: int, speed: tuple[float, float], generator: torch.Generator) -> np.ndarray:
    """``[n]`` speeds drawn log-uniformly in ``speed = (v_min, v_max)`` (so 0.5:2 is as often half as double
    speed) from ``generator`` (the run's CPU generator: resuming repeats the draws)."""
    lo, hi = np.log(speed[0]), np.log(speed[1])
    u = torch.rand(n, generator=generator, dtype=torch.float64).numpy()
    return np.exp(lo + u * (hi - lo))


def speed_source(src: TripletSource, seq_len: int, mode: str, speed: tuple[float, float] | None,
                 generator: torch.Generator) -> TripletSource:
    """``src`` with every query window re-sampled at its own random speed (one epoch's draw;
    :func:`~seqnet.sequence.windows.speed_windows`); the positions, hence positives and negatives, stay
    the query frames'. ``speed`` None: ``src`` itself (and the generator is not advanced)."""
    if speed is None or src.q_items is None or src.q_bounds is None:
        return src
    v = draw_speeds(src.n_queries, speed, generator)
    idx = speed_windows(src.q_items, seq_len, mode, v, src.q_bounds)
    return dataclasses.replace(src, q_idx=torch.as_tensor(idx, dtype=torch.long, device=src.q_idx.device))
