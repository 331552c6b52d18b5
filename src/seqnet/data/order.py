"""The order of the images of a folder: natural sort of their names, numbers compared by value.

Embedded numbers compare as integers (``img-2.png`` before ``img-10.png``). Names that are one decimal number
between a common prefix and suffix, as frame exporters name frames by their time (``0.25.png``, ``1.5.png``,
``2.png``), are ordered by that number's value: a natural sort would read ``1.25`` and ``1.5`` as 1, 25 and
1, 5 and put ``1.png`` after ``1.75.png``, scrambling the route within every second. Names whose fractions all
have one length (``1.05``, ``1.10``, or none) keep the natural order, which is then the same; a fraction of
several digits ending in 0 (``v1.10``) reads as a version number, and keeps the natural order too.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from decimal import Decimal

_DECIMAL_NAME = re.compile(r"^(.*?)(\d+(?:\.\d+)?)(\D*)$")  # prefix, the one decimal number, a digit-free suffix


def natural_key(text: str) -> list:
    """Sort key that orders embedded numbers numerically (``a2`` < ``a10``)."""
    return [int(t) if t.isdecimal() else t.lower() for t in re.split(r"(\d+)", text)]  # "²".isdigit(), not int


def decimal_values(names: Sequence[str]) -> list[Decimal] | None:
    """The number each of ``names`` is, when every name is one decimal number between one common prefix and one
    common suffix (``0.25.png``, ``1.5.png``, ``2.png``) and their fractions differ in length (so that the natural
    order would differ from the numbers' order); else None (also for version-like fractions such as ``1.10``)."""
    parts = [_DECIMAL_NAME.match(n) for n in names]
    if len(names) < 2 or not all(parts):
        return None
    if len({(m[1], m[3]) for m in parts if m}) != 1:
        return None
    fractions = [m[2].partition(".")[2] for m in parts if m]
    if len({len(f) for f in fractions}) < 2 or any(len(f) > 1 and f.endswith("0") for f in fractions):
        return None
    return [Decimal(m[2]) for m in parts if m]


def name_order(names: Sequence[str]) -> list[int]:
    """The indices of ``names`` in image order: by value for decimal-number names (:func:`decimal_values`), else
    the natural order (:func:`natural_key`)."""
    values = decimal_values(names)
    if values is None:
        return sorted(range(len(names)), key=lambda i: natural_key(names[i]))
    return sorted(range(len(names)), key=lambda i: (values[i], natural_key(names[i])))
