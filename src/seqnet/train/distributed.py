"""Distributed training under ``torchrun`` (DistributedDataParallel): the process group, this
process's place in it and the few collectives training needs (see docs/training.md).

:func:`joined` reads torchrun's variables (``WORLD_SIZE``, ``RANK``, ``LOCAL_RANK``,
``MASTER_ADDR``, ``MASTER_PORT``), initialises the process group (gloo for CPU tensors, plus NCCL
for CUDA tensors when CUDA is present) and destroys it on exit, errors included. Without those
variables (or with ``WORLD_SIZE=1``) the world is this one process and every helper is the identity:
no process group, no communication, the same numbers as before distributed training existed.

Rank 0 alone touches the run directory; :meth:`World.rank0` runs such a step there and hands its
result, or its exception, to every rank, so that all ranks stop together with the same error (a
copy is marked ``reported_elsewhere``: the CLI prints it once, on rank 0). Ranks other than 0 log
warnings and errors only and draw no progress bar.
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import logging
import math
import os
import pickle
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

from ..core.devices import get_device
from ..core.errors import ConfigError, ResourceError
from ..core.lazy import lazy_module
from ..core.log import logger
from ..core.progress import progress_mode

torch = lazy_module("torch")
nn = lazy_module("torch.nn")

T = TypeVar("T")
ENV = ("WORLD_SIZE", "RANK", "LOCAL_RANK", "MASTER_ADDR", "MASTER_PORT")


@dataclasses.dataclass(frozen=True)
class World:
    """This process's place among the training processes (``size`` 1: no process group)."""

    size: int = 1
    rank: int = 0
    local_rank: int = 0
    backend: str = "none"

    @property
    def is_rank0(self) -> bool:
        return self.rank == 0

    def describe(self) -> str:
        """``"world size N (backend ...)"`` for the start line."""
        return f"world size {self.size} ({self.backend})"

    def device(self, name: str) -> torch.device:
        """The training device of this rank: ``get_device(name)``; for CUDA in a world of several
        processes, ``cuda:LOCAL_RANK`` (made the current CUDA device, as NCCL needs)."""
        dev = get_device(name)
        if self.size == 1 or dev.type != "cuda":
            return dev
        if dev.index is not None:
            raise ConfigError(f"device {name!r}: under torchrun every rank uses cuda:LOCAL_RANK (hint: --device cuda "
                              "or auto, and CUDA_VISIBLE_DEVICES to choose the GPUs)")
        if self.local_rank >= torch.cuda.device_count():
            raise ResourceError(f"rank {self.rank} has LOCAL_RANK {self.local_rank} but this node has "
                                f"{torch.cuda.device_count()} CUDA device(s) (hint: --nproc-per-node <= the GPUs)")
        dev = torch.device("cuda", self.local_rank)
        torch.cuda.set_device(dev)
        return dev

    def rank0(self, fn: Callable[[], T]) -> T:
        """``fn()`` on rank 0 only; its (picklable) result, or its exception, reaches every rank."""
        if self.size == 1:
            return fn()
        import torch.distributed as dist

        box: list[Any] = [None]
        error: BaseException | None = None
        if self.rank == 0:
            try:
                box[0] = (True, fn())
            except Exception as e:  # noqa: BLE001 - every rank must learn that rank 0 failed
                error, box[0] = e, (False, _shareable(e))
        dist.broadcast_object_list(box, src=0)
        ok, value = box[0]
        if error is not None:
            raise error
        if not ok:
            value.reported_elsewhere = True  # rank 0 reports it
            raise value
        return value

    def agree(self, fn: Callable[[], T]) -> T:
        """``fn()`` on every rank; when it fails on some rank, every rank raises the first failure
        (rank 0 reports it, the others' copies are marked ``reported_elsewhere``)."""
        if self.size == 1:
            return fn()
        import torch.distributed as dist

        value, error = None, None
        try:
            value = fn()
        except Exception as e:  # noqa: BLE001 - the other ranks must learn it
            error = e
        outcomes: list[Any] = [None] * self.size
        dist.all_gather_object(outcomes, None if error is None else _shareable(error))
        failed = [e for e in outcomes if e is not None]
        if not failed:
            return value  # type: ignore[return-value]
        first = error if error is not None else failed[0]
        if self.rank != 0:
            first.reported_elsewhere = True  # type: ignore[attr-defined]
        raise first

    def shares(self, n: int, batch: int) -> torch.Tensor:
        """``[n]`` bool: the queries of this rank among ``n`` consecutive ones cut in batches of
        ``batch``: query ``j`` of a batch of ``m`` belongs to rank ``j * size // m`` (contiguous,
        balanced shares; a batch smaller than the world leaves some ranks without a query)."""
        pos = torch.arange(n)
        m = torch.clamp(n - (pos // batch) * batch, max=batch)
        return (pos % batch) * self.size // m == self.rank

    def part(self, n: int) -> slice:
        """This rank's contiguous share of ``n`` items (``ceil(n / size)`` each, the last ones fewer)."""
        chunk = math.ceil(n / self.size)
        return slice(min(n, self.rank * chunk), min(n, (self.rank + 1) * chunk))

    def gather_rows(self, x: torch.Tensor, n: int) -> torch.Tensor:
        """All ranks' :meth:`part` of ``n`` rows, ``x [part, C]`` here, as ``[n, C]`` on every rank."""
        if self.size == 1:
            return x
        import torch.distributed as dist

        chunk = math.ceil(n / self.size)
        padded = x.new_zeros((chunk, *x.shape[1:]))
        padded[: len(x)] = x
        out = [torch.empty_like(padded) for _ in range(self.size)]
        dist.all_gather(out, padded)
        return torch.cat(out)[:n]

    def merge_rows(self, own: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
        """``[S, C]``: row ``i`` from the rank whose ``own [S]`` (bool, one owner per row) marks it;
        ``values [own.sum(), C]`` are this rank's rows (an all-reduce sum over zeros elsewhere)."""
        if self.size == 1:
            return values
        import torch.distributed as dist

        out = values.new_zeros((len(own), *values.shape[1:]))
        out[own] = values
        dist.all_reduce(out)
        return out

    def sum_stats(self, stats: dict[str, float]) -> dict[str, float]:
        """``stats`` summed over the ranks (float64)."""
        if self.size == 1:
            return stats
        import torch.distributed as dist

        t = torch.tensor(list(stats.values()), dtype=torch.float64)
        dist.all_reduce(t)
        return dict(zip(stats, t.tolist(), strict=True))

    def wrap(self, model: nn.Module) -> nn.Module:
        """The module training calls: ``model`` itself, or a :class:`DistributedDataParallel` of it
        whose gradients are **summed** over the ranks (each rank's loss is its share of the batch mean)."""
        if self.size == 1:
            return model
        from torch.nn.parallel import DistributedDataParallel

        dev = next(model.parameters()).device
        ddp = DistributedDataParallel(model, device_ids=[dev.index] if dev.type == "cuda" else None)
        ddp.register_comm_hook(None, _sum_hook)
        return ddp


def _sum_hook(_state, bucket):  # noqa: ANN001, ANN202 - DDP checks real annotations; these would be strings
    """DDP communication hook: all-reduce sum of a gradient bucket (DDP's default divides by the size)."""
    import torch.distributed as dist

    return dist.all_reduce(bucket.buffer(), async_op=True).get_future().then(lambda f: f.value()[0])


def _lost_peer(e: BaseException) -> bool:
    """Whether ``e`` is a failed collective (a rank died or a connection broke), not a bug of ours."""
    import torch.distributed as dist

    text = str(e).lower()
    return isinstance(e, dist.DistError) or any(k in text for k in ("gloo", "nccl", "connection", "socket"))


def _shareable(e: BaseException) -> BaseException:
    """``e`` when it pickles (to reach the other ranks), else a RuntimeError with its text."""
    try:
        pickle.dumps(e)
        return e
    except Exception:  # noqa: BLE001 - any pickling failure
        return RuntimeError(f"{type(e).__name__}: {e}")


def _env_int(key: str, default: int | None = None) -> int:
    raw = os.environ.get(key)
    if raw is None and default is not None:
        return default
    try:
        return int(raw)  # type: ignore[arg-type]
    except (TypeError, ValueError) as err:
        raise ConfigError(f"environment variable {key}={raw!r} must be an integer (hint: start distributed "
                          "training with torchrun, see docs/training.md)") from err


def env_world() -> World:
    """The world torchrun's variables describe (``WORLD_SIZE`` unset or 1: a single process)."""
    size = _env_int("WORLD_SIZE", 1)
    if size <= 1:
        return World()
    missing = [k for k in ENV if k not in os.environ]
    if missing:
        raise ConfigError(f"WORLD_SIZE={size} but {', '.join(missing)} not set (hint: start distributed training "
                          "with torchrun --nproc-per-node N -m seqnet train ...)")
    rank, local = _env_int("RANK"), _env_int("LOCAL_RANK")
    if not 0 <= rank < size or local < 0:
        raise ConfigError(f"RANK={rank} / LOCAL_RANK={local} do not fit WORLD_SIZE={size}")
    return World(size, rank, local, _backend())


def _backend() -> str:
    import torch.distributed as dist

    if not dist.is_available():
        raise ResourceError("WORLD_SIZE > 1 but this torch build has no torch.distributed")
    return "cpu:gloo,cuda:nccl" if torch.cuda.is_available() and dist.is_nccl_available() else "gloo"


_STORES: dict[tuple[str, ...], Any] = {}  # this process's rendezvous store (it outlives process groups)
_JOINS = itertools.count()


def _init(world: World) -> None:
    """The default process group on torchrun's store, under a prefix of its own for every join: a
    model trained before keeps DDP hooks that keep its group alive, whose keys a new group must not read."""
    import torch.distributed as dist

    key = tuple(os.environ[k] for k in ENV)
    if key not in _STORES:
        _STORES[key] = next(dist.rendezvous("env://"))[0]
    store = dist.PrefixStore(f"seqnet/{next(_JOINS)}", _STORES[key])
    dist.init_process_group(backend=world.backend, store=store, rank=world.rank, world_size=world.size)


@contextlib.contextmanager
def joined() -> Iterator[World]:
    """This process's :class:`World` inside the block: the process group is initialised here (unless
    the caller did) and destroyed on exit; a failed collective (another rank died or left) becomes a
    :class:`ResourceError`. Ranks other than 0 log only warnings and draw no progress bar."""
    world = env_world()
    if world.size == 1:
        yield world
        return
    import torch.distributed as dist

    mine = not dist.is_initialized()
    if mine:
        _init(world)
    elif dist.get_world_size() != world.size or dist.get_rank() != world.rank:
        raise ConfigError(f"the process group (size {dist.get_world_size()}, rank {dist.get_rank()}) does not match "
                          f"WORLD_SIZE={world.size} / RANK={world.rank}")
    level = logger.level
    try:
        if world.rank > 0:
            logger.setLevel(max(logger.getEffectiveLevel(), logging.WARNING))
        with progress_mode(False) if world.rank > 0 else contextlib.nullcontext():
            yield world
    except (dist.DistError, RuntimeError) as e:
        if not _lost_peer(e):
            raise
        raise ResourceError(f"distributed training stopped on rank {world.rank}: {' '.join(str(e).split())[:300]} "
                            "(another rank failed or left: see its error; continue with --resume RUN)") from e
    finally:
        logger.setLevel(level)
        if mine:
            dist.destroy_process_group()
