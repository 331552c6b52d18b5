"""The order of the images of a folder: natural sort of their names, numbers compared by value.

Embedded numbers compare as integers (``img-2.png`` before ``img-10.png``). Names that are one decimal number
between a common prefix and suffix, as frame exporters name frames by their time (``0.25.png``, ``1.5.png``,
``2.png``), are ordered by that number's value: a natural sort would read ``1.25`` and ``1.5`` as 1, 25 and
1, 5 and put ``1.png`` after ``1.75.png``, scrambling the route within every second. Names whose fractions all
have one length (``1.05``, ``1.10``, or none) keep the natural order, which is then the same; a fraction of
several digits ending in 0 (``v1.10``) reads as a version number, and keeps the natural order too.

A list of names in plain text order (``ls``, Python's ``sorted()``: ``img_1``, ``img_10``, ``img_100``, ``img_2``)
that the natural order would change is almost surely not the route's order: :func:`text_sorted_pair` finds it,
:func:`text_order_line` says it in one line, and :func:`frame_order_lines` of a dataset whose ground truth is
frame indices (``--frame-aligned``, ``--positives``), where no position shows it (``seqnet dataset check``, ``eval``).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from decimal import Decimal
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .traverse import Dataset

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


def text_sorted_pair(names: Sequence[str]) -> tuple[str, str] | None:
    """``(a, b)``: the first name listed before one it should follow (``img_10.png`` before ``img_2.png``), when
    ``names`` are in plain text order (Python's ``sorted()``, or ``ls``'s case-blind one) and the numbers in them
    make :func:`name_order` another; None for names in natural order, whose numbers change nothing, or in any
    other order (chosen on purpose)."""
    if len(names) < 2 or not (_ascending(names, str) or _ascending(names, str.lower)):
        return None
    rank = [0] * len(names)
    for r, i in enumerate(name_order(names)):
        rank[i] = r
    smallest = [len(names) - 1] * len(names)  # smallest[i]: the index of the least rank in names[i:]
    for i in range(len(names) - 2, -1, -1):
        smallest[i] = i if rank[i] < rank[smallest[i + 1]] else smallest[i + 1]
    for i in range(len(names) - 1):
        j = smallest[i + 1]
        if rank[j] < rank[i] and names[i].lower() <= names[j].lower():  # not a mere difference of case
            return names[i], names[j]
    return None


def _ascending(names: Sequence[str], key: Callable[[str], str]) -> bool:
    return all(key(a) <= key(b) for a, b in zip(names, names[1:], strict=False))


def text_order_line(names: Sequence[str], what: str) -> str | None:
    """One line saying that ``what`` (a list file, a traverse) is in text order, not in its names' numeric order
    (:func:`text_sorted_pair`), and how to list it; None when it is not."""
    pair = text_sorted_pair(names)
    if pair is None:
        return None
    return (f"{what} is in text order, not by the numbers in its names: {pair[0]!r} comes before {pair[1]!r} (a "
            "plain ls or sorted()?); the frames follow this order, so sequence windows, --frame-aligned and "
            "--positives pair frames far apart; hint: list the images by number: ls -v (or sort -V), or in Python "
            "sorted(names, key=seqnet.data.order.natural_key)")


def frame_order_lines(ds: Dataset) -> list[str]:
    """The :func:`text_order_line` of each traverse of ``ds`` with names, when its positions are frame indices
    (frame-aligned ground truth or explicit positives: real positions show a scrambled order themselves)."""
    if ds.position_unit != "frames":
        return []
    found = [text_order_line(t.names, f"the {side} traverse") if t.names is not None else None
             for side, t in (("query", ds.query), ("reference", ds.reference))]
    return [line for line in found if line]
