"""The guide in the training loop: what a run will cost and what to change, said before it starts, and the
checks that speak up while it runs.

Before the first epoch :func:`plan` estimates, from N (training queries and reference windows), D, out, L
and w: the peak memory (held at the memory check, :class:`Budget`, + :func:`seqnet.train.memory.train_bytes`:
:func:`check_memory` refuses, before any work, more than is available), the time per epoch (the epoch's
multiply-adds, :func:`epoch_flops`, over the device's rate measured by timing one matrix product like the
model's, :func:`measured_rate`, plus :data:`STEP_SECONDS` per batch, a measured constant) and the size of the
two checkpoints; :func:`plan_text` is the one block logged (INFO), then the advice (:func:`advice`, one
warning each, kept in ``Run.advice``): PCA (``--pca D``) when D is above :data:`PAPER_PCA_DIM` (the paper
reduces NetVLAD to 4096) or not below the windows the layer is learnt from (training queries and reference
windows), a smaller ``--out-dims`` / ``--w`` when the checkpoints pass :data:`CHECKPOINT_ADVISED_BYTES` or the
memory half of what is available (over all of it, training was refused).

The checks that speak up while a run trains (a val split too small, no active triplet): :mod:`seqnet.train.watch`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any

from ..core.devices import get_device
from ..core.errors import DatasetError
from ..core.lazy import lazy_module
from ..core.memory import available_bytes, check_fits, gib, human_bytes, rss_bytes
from ..data.traverse import Dataset
from ..describe.pca import PAPER_PCA_DIM, suggested_pca_dims
from .config import TrainConfig
from .losses import LOSSES
from .memory import memory_hint, train_bytes
from .pca_cost import PcaAdvice

torch = lazy_module("torch")

CHECKPOINT_ADVISED_BYTES = 500 * 2**20  # best.pt + last.pt above this: advise fewer dimensions
# seconds of each optimiser step beyond its FLOPs (indexing, the loss, Python): measured 2026-12-03 on the
# shared 2-core CPU, S_5 on `seqnet synth --places 2000` (D = 64, 74 batches an epoch): 0.1-0.3 s per epoch,
# SGD and Adam, validation included (the 0.025 s used before made the plan 1.9 s per epoch, 6-19x too long)
STEP_SECONDS = 0.003
OPTIMIZER_COPIES = {"sgd": 1, "adam": 2}  # state per weight kept in last.pt (momentum / the two moments)
# bytes per second of writing a checkpoint (torch.save to a temporary, renamed): 2.3 GiB in 11.6 s measured on
# this project's shared machine; each epoch writes last.pt (and best.pt when val improves)
WRITE_BYTES_PER_S = 200e6
UPDATE_PROBE = 1 << 22  # weights of the tensor an optimiser step is timed on (scaled to the model's weights)


@dataclasses.dataclass(frozen=True)
class Budget:
    """The process's memory at the check before training: ``held`` bytes resident (Python, torch, the dataset:
    0.26 GiB or more), ``free`` what it may still allocate (None: unknown); the peak adds ``train_bytes``."""

    held: int
    free: int | None

    @classmethod
    def now(cls) -> Budget:
        return cls(rss_bytes(), available_bytes())


@dataclasses.dataclass(frozen=True)
class Plan:
    """What a training run will cost (estimates; see the module docstring).

    Attributes:
        n_queries, n_refs: training queries and reference windows; n_frames: the training split's frames
            (both traverses: what a PCA fitted on it sees).
        in_dims, out_dims, seq_len, w, epochs: the model and the epochs left to run.
        weights: parameters of the model; checkpoint_bytes: ``best.pt`` + ``last.pt`` on disk.
        peak_bytes: estimated peak memory of the process, ``held_bytes`` (held before training) included;
            available: what it may hold (``held_bytes`` + what it may still allocate; None: unknown).
        flops: multiply-adds (x2) of one epoch; rate: the device's measured FLOP/s; device: its name;
            batch_size: queries per optimiser step.
    """

    n_queries: int
    n_refs: int
    n_frames: int
    in_dims: int
    out_dims: int
    seq_len: int
    w: int
    epochs: int
    weights: int
    checkpoint_bytes: int
    peak_bytes: int
    available: int | None
    flops: float
    rate: float
    device: str
    batch_size: int = 16
    update_seconds: float = 0.0
    held_bytes: int = 0
    memory_hint: str = ""

    @property
    def epoch_seconds(self) -> float:
        """Estimated seconds per epoch: the FLOPs at the measured rate, :data:`STEP_SECONDS` and the optimiser's
        update (``update_seconds``, measured) per batch, and writing the checkpoints (:data:`WRITE_BYTES_PER_S`)."""
        steps = math.ceil(self.n_queries / self.batch_size)
        extra = (steps + 1) * STEP_SECONDS + steps * self.update_seconds + self.checkpoint_bytes / WRITE_BYTES_PER_S
        return self.flops / self.rate + extra if self.rate > 0 else math.nan


def epoch_flops(conf: TrainConfig, in_dims: int, n_queries: int, n_refs: int, n_val: int = 0) -> float:
    """Floating-point operations of one epoch (an upper bound: every query with ``n_negatives`` triplets):
    the mining descriptors of the ``n_refs`` reference windows at every refresh and of the queries, the
    query-reference distances, forward and backward (x3) of each query's 2 + K windows, and validation's
    ``n_val`` windows. One window through the model is one product by its ``[D w, out]`` weight,
    ``2 w D out`` (:meth:`seqnet.sequence.model.SeqNet.forward`; a framewise loss's window: ``L_m`` frames
    through S_1); the backward pass's weight gradient about as much again, the update a little more."""
    out = int(conf.out_dims or in_dims)
    window = 2.0 * conf.w * in_dims * out * (conf.window_len if LOSSES[conf.loss].framewise else 1)
    refreshes = math.ceil(n_queries / conf.cache_refresh) if conf.cache_refresh else 1
    mining = window * (refreshes * n_refs + n_queries) + 2.0 * n_queries * n_refs * out
    steps = 3.0 * window * n_queries * (2 + conf.n_negatives)
    return mining + steps + window * n_val


def measured_rate(in_dims: int, out_dims: int, device: Any, repeats: int = 3, min_seconds: float = 0.02) -> float:
    """FLOP/s of the device on a ``[B, D] x [D, min(out, 1024)]`` float32 product (the model's kind of
    work; B from 256 to 65536 rows, for about 1e8 operations), the best of ``repeats`` timings of a run of
    products lasting at least ``min_seconds`` each, after a warm-up of at least ``min_seconds``: a process's
    first products run many times slower (the thread pool starting; measured 2-4 GFLOP/s on the first product
    of a process against 160-195 after, on 2 CPU cores), and one product of this size takes well under a
    millisecond there, too short to time alone."""
    cols = max(1, min(out_dims, 1024))
    rows = int(min(65536, max(256, 1e8 // (2 * in_dims * cols))))
    x = torch.randn(rows, in_dims, device=device)
    weight = torch.randn(in_dims, cols, device=device)
    sync = torch.cuda.synchronize if getattr(device, "type", str(device)).startswith("cuda") else (lambda: None)

    def timed(n: int) -> float:
        sync()
        t0 = time.perf_counter()
        for _ in range(n):
            (x @ weight).sum().item()
        sync()
        return time.perf_counter() - t0

    spent = 0.0
    while spent < min_seconds:  # warm-up: products for at least min_seconds
        spent += timed(1)
    n = 1
    while (first := timed(n)) < min_seconds:  # a run of products long enough to time
        n *= 2
    best = min([first] + [timed(n) for _ in range(repeats - 1)]) / n
    return 2.0 * rows * in_dims * cols / max(best, 1e-9)


def measured_update(weights: int, optimizer: str, device: Any, repeats: int = 3) -> float:
    """Seconds of one optimiser step (``adam``, else SGD with momentum) on ``weights`` weights: the best of
    ``repeats`` steps on a tensor of at most :data:`UPDATE_PROBE` weights, after one warm-up step (it allocates
    the state), scaled linearly (the update is a few passes over the weights, their gradient and its state)."""
    n = max(1, min(weights, UPDATE_PROBE))
    param = torch.nn.Parameter(torch.zeros(n, device=device))
    param.grad = torch.randn(n, device=device)
    opt = torch.optim.Adam([param], lr=1e-4) if optimizer == "adam" else torch.optim.SGD([param], lr=1e-4,
                                                                                              momentum=0.9)
    sync = torch.cuda.synchronize if getattr(device, "type", str(device)).startswith("cuda") else (lambda: None)
    best = math.inf
    for i in range(repeats + 1):
        sync()
        t0 = time.perf_counter()
        opt.step()
        sync()
        if i:
            best = min(best, time.perf_counter() - t0)
    return best * weights / n


def plan(conf: TrainConfig, in_dims: int, n_queries: int, n_refs: int, n_frames: int, n_val: int,
         epochs: int, device: Any, n_ref_frames: int | None = None, n_query_frames: int | None = None,
         rate: float | None = None, budget: Budget | None = None) -> Plan:
    """The :class:`Plan` of training ``conf`` on ``in_dims``-D descriptors (``rate``: the device's FLOP/s,
    measured when None; ``n_ref_frames`` / ``n_query_frames``: the dataset's, for the memory estimate;
    ``budget``: the memory check's, :meth:`Budget.now` when None)."""
    out = int(conf.out_dims or in_dims)
    weights = in_dims * out * conf.w + out
    copies = OPTIMIZER_COPIES.get(conf.optimizer, 2)
    checkpoint = 4 * weights * (2 + copies)  # best.pt: the weights; last.pt: the weights and the optimiser state
    spill = getattr(device, "type", str(device)) == "cpu"
    b = budget or Budget.now()
    sizes = (in_dims, n_ref_frames or n_refs, n_query_frames or n_queries)
    peak = b.held + train_bytes(conf, *sizes, spill, n_queries)
    hint = memory_hint(conf, *sizes, n_queries, spill, suggested_pca_dims(n_frames, in_dims))
    return Plan(n_queries, n_refs, n_frames, in_dims, out, conf.seq_len, conf.w, epochs, weights, checkpoint, peak,
                None if b.free is None else b.held + b.free, epoch_flops(conf, in_dims, n_queries, n_refs, n_val),
                measured_rate(in_dims, out, device) if rate is None else rate, str(device), conf.batch_size,
                measured_update(weights, conf.optimizer, device) if rate is None else 0.0, b.held, hint)


def suggested_pca(p: Plan) -> int:
    """The PCA dimension to name: :func:`seqnet.describe.pca.suggested_pca_dims` of the training frames (what a PCA
    fitted on the train split sees) and D, the one size every message suggests."""
    return suggested_pca_dims(p.n_frames, p.in_dims)


def names_pca(p: Plan) -> bool:
    """Whether :func:`advice` would name a PCA (then measured first: :func:`seqnet.train.pca_cost.pca_advice`)."""
    over_half = p.available is not None and p.peak_bytes > p.available / 2
    return suggested_pca(p) < p.in_dims and (p.in_dims > PAPER_PCA_DIM or _windows_below(p) or over_half or
                                              p.checkpoint_bytes > CHECKPOINT_ADVISED_BYTES)


def _windows_below(p: Plan) -> bool:
    return p.in_dims >= p.n_queries + p.n_refs and p.in_dims > 8


def advice(p: Plan, pca: PcaAdvice | None = None) -> list[str]:
    """What to change, and how (empty: nothing to say); ``pca``: the PCA to name and what it costs (measured:
    named as the way only when cheap, else its cost and the other ways; None: :func:`suggested_pca`, unmeasured)."""
    out = []
    pca = pca or PcaAdvice(suggested_pca(p))
    why = ""
    if p.in_dims > PAPER_PCA_DIM:
        why = (f"D = {p.in_dims} is above {PAPER_PCA_DIM} (the SeqNet paper reduces its descriptors to 4096 with "
               "PCA)")
    elif _windows_below(p):
        why = (f"D = {p.in_dims} is not below the {p.n_queries + p.n_refs} windows the layer is learnt from "
               f"({p.n_queries} training queries, {p.n_refs} reference windows): its {p.weights:,} weights (D x out x "
               "w) overfit them")
    others = ["--w 1"] * (p.w > 1) + ["a smaller --out-dims (e.g. 512)"] * (p.out_dims > 512)
    if why and pca.advised:
        cost = f"; measured, {pca.cost_text()}" if pca.cost is not None else ""
        out.append(f"{why}: reduce it with {pca.flag} (fitted on the train split only{cost})")
    elif why:
        out.append(f"{why}; but {pca.cost_text()}, so it is not advised here; fewer weights that keep every dimension: "
                   f"{', '.join(others) or 'more training frames'}")
    if p.checkpoint_bytes > CHECKPOINT_ADVISED_BYTES:
        ways = [f"fewer dimensions ({pca.flag})"] * (pca.dims < p.in_dims and pca.advised) + others
        out.append(f"the checkpoints take {human_bytes(p.checkpoint_bytes)} (best.pt {human_bytes(4 * p.weights)}, "
                   f"last.pt with the optimiser state): {', '.join(ways) or 'fewer dimensions'} shrink them (the "
                   "weights are D x out x w)")
    if p.available is not None and p.peak_bytes > p.available / 2:
        cost = f" ({pca.cost_text()})" if not pca.advised and f"--pca {pca.dims}" in p.memory_hint else ""
        out.append(f"the estimated peak memory {human_bytes(p.peak_bytes)} is over half of the "
                   f"{human_bytes(p.available)} available; what lowers it most: {p.memory_hint}{cost}")
    return out


def plan_text(p: Plan) -> str:
    """The block logged before training: the model, memory, time and checkpoints (the advice, :func:`advice`, is
    logged apart, as warnings: a Python caller sees them without an INFO handler)."""
    avail = f" of {human_bytes(p.available)} available" if p.available is not None else ""
    held = f" ({human_bytes(p.held_bytes)} held before training)" if p.held_bytes else ""
    total = p.epoch_seconds * p.epochs
    lines = [f"training plan: S_{p.seq_len} (w={p.w}, D {p.in_dims}->{p.out_dims}): {p.weights:,} weights, "
             f"{p.n_queries} queries, {p.n_refs} reference windows, {p.n_frames} training frames",
             f"  peak memory  about {human_bytes(p.peak_bytes)}{held}{avail}",
             f"  time         about {_duration(p.epoch_seconds)} per epoch on {p.device} (the device's measured "
             f"{p.rate / 1e9:.1f} GFLOP/s, every negative active), {p.epochs} epoch{'s' * (p.epochs != 1)}: about "
             f"{_duration(total)}",
             f"  checkpoints  about {human_bytes(p.checkpoint_bytes)} on disk (best.pt + last.pt)"]
    return "\n".join(lines)


def _duration(s: float) -> str:
    if not math.isfinite(s):
        return "unknown"
    return (f"{s * 1000:.0f} ms" if s < 1 else f"{s:.1f} s" if s < 120 else f"{s / 60:.1f} min" if s < 7200
            else f"{s / 3600:.1f} h")


def _train_frames(dataset: Dataset, conf: TrainConfig) -> int:
    """The query frames of the train split: at most that many training queries (a bad split fails later)."""
    try:
        return len(dataset.split(conf.train_split).query)
    except DatasetError:
        return len(dataset.query)


def _fit_frames(dataset: Dataset, conf: TrainConfig) -> int:
    """The frames of both traverses of the train split (what a ``--pca`` is fitted on; the whole dataset's when the
    split is bad: it fails later)."""
    try:
        part = dataset.split(conf.train_split)
    except DatasetError:
        part = dataset
    return len(part.reference) + len(part.query)


def check_memory(conf: TrainConfig, dataset: Dataset) -> Budget:
    """Refuse before any work (ResourceError, exit 1, naming both and what lowers them) a training run whose
    :func:`~seqnet.train.memory.train_bytes` (a batch of at most the train split's query frames) is over what
    the process may still allocate; the :class:`Budget` checked (the plan's)."""
    d, out = dataset.query.dim, int(conf.out_dims or dataset.query.dim)
    spill = get_device(conf.device).type == "cpu"  # the mining cache spills when large (one process)
    n_train, budget = _train_frames(dataset, conf), Budget.now()
    n_ref, n_query = len(dataset.reference), len(dataset.query)
    check_fits(train_bytes(conf, d, n_ref, n_query, spill, n_train),
               f"training S_{conf.seq_len} (w={conf.w}, D={d}->{out}, {conf.optimizer}: the weights alone are "
               f"{gib(4 * d * out * conf.w)})",
               memory_hint(conf, d, n_ref, n_query, n_train, spill, suggested_pca_dims(_fit_frames(dataset, conf), d)),
               budget.held,
               budget.free)
    return budget
