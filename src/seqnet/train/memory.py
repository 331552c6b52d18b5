"""The memory a training run needs beyond what its process holds (:func:`train_bytes`, what the memory check
refuses on and the plan states) and what lowers it most (:func:`memory_hint`: the options that shrink the
largest terms, with what each saves; never a value the run already has).

The terms, measured 2026-12-04 on the CPU (torch 2.13; peak RSS of one optimiser step, ``VmHWM`` reset before
it, two batch sizes: the batch is the slope): the weights with their gradients, optimiser state and the step's
temporaries (:data:`WEIGHT_COPIES`), the mining cache and its blocks in flight, and one batch (its windows,
:func:`window_floats`).
"""

from __future__ import annotations

import math

from ..core.memory import human_bytes
from .config import TrainConfig
from .losses import LOSSES

# what training loads beyond the process at its memory check (torch with the dataset): the first optimiser's
# imports (torch.optim: 71 MiB), autograd, the TensorBoard writer (5 MiB) and the plan's timing products; measured
# 2026-12-04, torch 2.13 CPU: 98-100 MiB between the check and the peak of S_5 on synth D = 64 and D = 2048
LIBRARY_BYTES = 96 << 20
# weight-sized arrays at the optimiser step (torch.optim on the CPU, weight decay on): the weights, their gradient
# and the decay's sum (grad + wd w, a new array); then SGD's momentum (4), or Adam's two moments and its update's
# exp_avg_sq.sqrt() and the quotient by the bias correction (7). Measured 2026-12-04, torch 2.13 CPU: peak RSS of
# one step on 50 M weights, 4.0 and 7.0 weight-sized arrays (tests/train/test_train_memory.py); Adam costed 6
# until then planned 5.2 GiB for D = 8192 S_5 w = 3 (201 M weights), which peaked at 5.78 GiB
WEIGHT_COPIES = {"sgd": 4, "adam": 7}
OUT_FLOATS = 7  # floats per output dimension of a window in the backward pass (embeddings, distances, gradients)


def window_floats(conf: TrainConfig, in_dims: int, out: int) -> int:
    """Floats one window of a batch (a query, its positive or a negative) holds at the step's peak
    (:meth:`seqnet.sequence.model.SeqNet.forward`): in the forward pass its ``[L, D]`` frames gathered and
    concatenated (2 L D), the tap average ``[w, D]`` (when w < L) and its flattened copy (when w > 1);
    in the backward pass the frames, the flattened input kept for the weight gradient and
    :data:`OUT_FLOATS` out-sized arrays. A framewise loss's window is ``window_len`` frames (widened reference
    windows: + 2 ``ref_pad``) of S_1. Measured 2026-12-04 (peak RSS of a step at two batch sizes,
    tests/train/test_train_memory.py; L = 5, D = 2048 -> 64): 14.5 D floats a window at w = 5 (planned 15.1),
    13.4 at w = 3 (16.1), 6.2 at w = 1 (11.1: an upper bound)."""
    if LOSSES[conf.loss].framewise:
        return (conf.window_len + 2 * conf.ref_pad) * (2 * in_dims + OUT_FLOATS * out)
    length, w = conf.seq_len, conf.w
    tap = 0 if w == length else w  # [w, D] tap average (the identity at w = L)
    flat = w if w > 1 else 0  # [w D] flattened taps (a view at w = 1)
    kept = flat or tap or length  # what the weight gradient reads
    return max(2 * length * in_dims + (tap + flat) * in_dims + 2 * out, (length + kept) * in_dims + OUT_FLOATS * out)


def train_bytes(conf: TrainConfig, in_dims: int, n_ref: int, n_query: int, spill: bool = False,
                n_train: int | None = None) -> int:
    """Estimated peak bytes of training ``conf`` on ``in_dims``-D descriptors with ``n_ref`` reference and
    ``n_query`` query frames (one process), beyond what the process holds before it: :data:`LIBRARY_BYTES`,
    the weights with their gradients, optimiser state and the step's temporaries (:data:`WEIGHT_COPIES`), the
    mining cache, its blocks in flight, and one batch: ``batch_size`` queries (at most the ``n_train`` training
    queries, default ``n_query``) of 2 + ``n_negatives`` windows each (:func:`window_floats`).

    The mining cache holds one descriptor per reference window (per frame for the framewise losses: about
    as many), unless ``spill`` (training on the CPU) sends one over ``SEQNET_SPILL_MB`` to a temporary file
    (:func:`seqnet.train.mining.compute_cache`); and one per window of the ``cache_refresh`` queries mined
    together (``window_len`` per window for the framewise losses). The frame descriptors themselves are the
    dataset's (a large memory map on the CPU is read in blocks, not copied)."""
    from ..core.memmaps import limit
    from ..search.blocks import COL_BLOCK_BYTES

    out = int(conf.out_dims or in_dims)
    weights = in_dims * out * conf.w + out
    per_window = conf.window_len if LOSSES[conf.loss].framewise else 1
    ref_cache = 4 * n_ref * out
    if spill and ref_cache > limit("SPILL"):
        ref_cache = 0  # in a spill file, read back one column block at a time
    n_train = n_query if n_train is None else min(n_train, n_query)
    mined = min(conf.cache_refresh or n_train, n_train)
    query_cache = 4 * mined * per_window * out
    blocks = min(COL_BLOCK_BYTES, 4 * n_ref * per_window * out) + 4 * 4 * min(2**24, mined * n_ref)  # [B, R] x 4
    batch = min(conf.batch_size, n_train) * (2 + conf.n_negatives) * window_floats(conf, in_dims, out)
    copies = WEIGHT_COPIES.get(conf.optimizer, max(WEIGHT_COPIES.values()))
    return LIBRARY_BYTES + 4 * (copies * weights + batch) + ref_cache + query_cache + blocks


def memory_hint(conf: TrainConfig, in_dims: int, n_ref: int, n_query: int, n_train: int, spill: bool,
                pca: int) -> str:
    """What lowers :func:`train_bytes` most: the options that change it (``--pca pca``, ``--out-dims``,
    ``--w 1``, ``--optimizer sgd``, ``--batch-size``), largest saving first, each with what it saves; an option
    is left out when the run already has that value or less (or saves nothing)."""
    out, batch = int(conf.out_dims or in_dims), min(conf.batch_size, max(n_train, 1))
    options: list[tuple[str, int, int]] = []  # (flag, in_dims, the changed configuration's out_dims)
    if pca < in_dims:
        options.append((f"--pca {pca}", pca, pca if out == in_dims else out))
    smaller = 512 if out > 512 else 2 ** int(math.log2(max(out - 1, 1)))
    if smaller >= 8:
        options.append((f"--out-dims {smaller}", in_dims, smaller))
    base = train_bytes(conf, in_dims, n_ref, n_query, spill, n_train)
    said = []
    for flag, d, o in options:
        said.append((base - train_bytes(conf.merge(out_dims=o), d, n_ref, n_query, spill, n_train), flag))
    changes = {"--w 1": {"w": 1}, "--optimizer sgd": {"optimizer": "sgd"}, f"--batch-size {max(1, batch // 4)}":
               {"batch_size": max(1, batch // 4)}}
    for flag, change in changes.items():  # a value the run already has saves nothing: dropped below
        said.append((base - train_bytes(conf.merge(**change), in_dims, n_ref, n_query, spill, n_train), flag))
    said = sorted((s for s in said if s[0] > 0), reverse=True)
    where = {f"--pca {pca}": "; seqnet train, or seqnet dataset from-images"}
    return ", ".join(f"{flag} (saves about {human_bytes(s)}{where.get(flag, '')})" for s, flag in said) or \
        "a smaller dataset"
