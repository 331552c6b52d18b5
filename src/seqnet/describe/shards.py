"""Describing one shard of an image list: ``seqnet describe ... --shard k/N`` (docs/describe.md).

A shard is the k-th (0-based, ``0 <= k < N``) of N contiguous slices of the image list. Slice
boundaries fall on multiples of the batch size, so every shard describes exactly the batches an
unsharded run would (CNN results can depend on what else is in the batch): merged shards are
byte-identical to one run. Fitted state (PCA, NetVLAD clusters) is fitted on the same images as an
unsharded run would pick, from the *whole* list, so every shard records the same provenance. Under
``torchrun`` (``WORLD_SIZE`` > 1) without ``--shard``, the shard is ``RANK/WORLD_SIZE`` and rank k writes
``<stem>.shard-k-of-N<suffix>`` beside ``--out`` (:func:`shard_output`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import re
from pathlib import Path
from typing import Any

from ..core.errors import ConfigError

SHARD_KEY = "shard"  # the provenance field of a shard output; the rest equals an unsharded run's
_SPEC = re.compile(r"^\s*(\d+)\s*/\s*(\d+)\s*$")


@dataclasses.dataclass(frozen=True)
class Shard:
    """Shard ``index`` of ``count`` (0-based: ``0 <= index < count``)."""

    index: int
    count: int

    def __post_init__(self) -> None:
        if self.count < 1 or not 0 <= self.index < self.count:
            raise ConfigError(f"shard {self.index}/{self.count} is out of range: k/N needs N >= 1 and k in "
                              f"0..{max(self.count - 1, 0)} (shards are numbered from 0)")

    def frames(self, n: int, batch_size: int) -> tuple[int, int]:
        """``(a, b)``: the images ``[a, b)`` of an ``n``-image list this shard describes; boundaries are
        multiples of ``batch_size`` (whole batches, as an unsharded run forms them). An empty shard is a
        :class:`ConfigError`."""
        batches = -(-n // batch_size)
        a = min(n, self.index * batches // self.count * batch_size)
        b = min(n, (self.index + 1) * batches // self.count * batch_size)
        if a >= b:
            raise ConfigError(f"shard {self.index}/{self.count} of {n} images in {batches} batches of {batch_size} "
                              f"is empty; hint: at most {batches} shards, or a smaller --batch-size")
        return a, b

    def record(self, n: int, batch_size: int, names: list[str]) -> dict[str, Any]:
        """The ``shard`` provenance field: index, count, image range, list size and a hash of the list."""
        a, b = self.frames(n, batch_size)
        return {"index": self.index, "count": self.count, "frames": [a, b], "images": n,
                "batch_size": batch_size, "list_sha1": names_digest(names)}


def names_digest(names: list[str]) -> str:
    """A short hash of an image list (its names in order)."""
    return hashlib.sha1("\n".join(names).encode()).hexdigest()[:16]


def parse_shard(text: str) -> Shard:
    """``"k/N"`` (0-based k) as a :class:`Shard`; a one-line :class:`ConfigError` naming a bad value."""
    m = _SPEC.match(str(text))
    if not m:
        raise ConfigError(f"--shard must be k/N with 0 <= k < N (0-based, e.g. 0/4 .. 3/4), got {text!r}")
    return Shard(int(m.group(1)), int(m.group(2)))


def env_shard() -> Shard | None:
    """The shard of this process under ``torchrun`` (``RANK/WORLD_SIZE`` when ``WORLD_SIZE`` > 1), else None."""
    values = {}
    for key in ("WORLD_SIZE", "RANK"):
        raw = os.environ.get(key, "1" if key == "WORLD_SIZE" else "")
        if not raw.strip().isdigit():
            if key == "RANK" and values["WORLD_SIZE"] <= 1:
                return None
            raise ConfigError(f"environment variable {key}={raw!r} must be a non-negative integer (hint: start "
                              "sharded describing with torchrun --nproc-per-node N -m seqnet describe ...)")
        values[key] = int(raw)
    if values["WORLD_SIZE"] <= 1:
        return None
    return Shard(values["RANK"], values["WORLD_SIZE"])


def shard_output(out: str | os.PathLike[str], shard: Shard) -> Path:
    """Where a torchrun rank writes its shard of ``out`` (every rank gets the same ``--out``):
    ``s.h5`` → ``s.shard-1-of-4.h5``."""
    out = Path(out)
    return out.with_name(f"{out.stem}.shard-{shard.index}-of-{shard.count}{out.suffix}")


def resolve_shard(shard: Shard | str | None) -> Shard | None:
    """``shard`` (a :class:`Shard` or ``"k/N"``), else the torchrun shard (:func:`env_shard`), else None;
    ``1`` shard (``0/1``) is no sharding."""
    s = parse_shard(shard) if isinstance(shard, str) else shard if shard is not None else env_shard()
    return None if s is None or s.count == 1 else s
