"""``--split NAME=A:B[,C:D]`` of the ``seqnet dataset`` builders: parsed, and the names checked (one rule for
every builder)."""

from __future__ import annotations

from ...core.errors import ConfigError
from ...core.log import logger

SPLIT_NAMES = ("train", "val", "test")  # the splits seqnet's commands use by default
RESERVED_SPLITS = {"all": "every query (eval --split all, train --train-split all): this split could never be chosen",
                   "none": "no validation (train --val-split none)"}
USE = ("seqnet's commands use the splits train, val and test by default (train trains on train and chooses the "
       "epoch on val; eval, index and localize take test)")


def parse_splits(items: list[str]) -> dict[str, dict[str, tuple[int, int]]] | None:
    """``NAME=A:B`` (queries A:B, the whole reference) or ``NAME=A:B,C:D`` (reference A:B, queries C:D) items →
    splits (None when there are none). A name given twice or a reserved name (:data:`RESERVED_SPLITS`, any case)
    is refused; a name other than :data:`SPLIT_NAMES` is one warning line each (did you mean ...? for a case
    variant)."""
    from ...data.traverse import parse_range_spec  # numpy: not on `seqnet --help`'s path

    out: dict[str, dict[str, tuple[int, int]]] = {}
    given: dict[str, str] = {}
    for item in items:
        name, _, spec = item.partition("=")
        rng = parse_range_spec(spec) if name and spec else None
        if rng is None:
            raise ConfigError(f"--split {item!r}: expected NAME=A:B or NAME=A:B,C:D (reference, query)")
        if name.lower() in RESERVED_SPLITS:
            raise ConfigError(f"--split {item}: the name {name!r} is reserved: {name.lower()} means "
                              f"{RESERVED_SPLITS[name.lower()]}; give the split another name (train, val or test)")
        if name in out:
            raise ConfigError(f"--split {item}: the split {name} is given twice (first --split {given[name]}); give "
                              "each split once, with one range (NAME=A:B or NAME=A:B,C:D)")
        if name not in SPLIT_NAMES:
            meant = next((n for n in SPLIT_NAMES if n == name.lower()), None)
            why = (f"split names are case-sensitive; did you mean {meant}? {USE}" if meant else
                   f"{USE}, so {name} is used only where a command names it (--split {name}, --train-split {name})")
            logger.warning("--split %s: %s", item, why)
        out[name], given[name] = rng, item
    return out or None
