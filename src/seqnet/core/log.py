"""The one logger of seqnet (``logging.getLogger("seqnet")``): INFO a few lines per stage, DEBUG with ``-v``."""

from __future__ import annotations

import logging
from collections.abc import Hashable
from typing import Any

logger = logging.getLogger("seqnet")
_SAID: set[Hashable] = set()  # the keys warn_once has said in this process


def warn_once(key: Hashable, msg: str, *args: Any) -> None:
    """Log ``msg % args`` as a warning the first time ``key`` comes in this process (a command may open one file
    more than once; the warning is about the file, not the opening)."""
    if key in _SAID:
        return
    _SAID.add(key)
    logger.warning(msg, *args)


def ordinal(n: int) -> str:
    """``1st``, ``2nd``, ``3rd``, ``4th``, ``11th``, ``12th``, ``13th``, ``21st`` ... (for messages)."""
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"


def counted(n: int, noun: str, plural: str | None = None) -> str:
    """``1 image``, ``2 images`` (``plural`` when the noun does not take an ``s``), for messages."""
    return f"{n} {noun if n == 1 else plural or noun + 's'}"
