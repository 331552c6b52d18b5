"""Numbers read from a file, checked before use: every count, size and setting has a range.

A number from ``map.json``, ``dataset.json``, a checkpoint's settings or a ground-truth file decides
allocations and loop lengths; :func:`number` refuses anything outside its range (and booleans, strings,
NaN) with one line naming the file's field, before the number is used.
"""

from __future__ import annotations

import math
from typing import Any

from ..core.errors import DatasetError
from .inputs import ErrorType

INDEX_MAX = 2**62  # an index or count read from a file (int64 arithmetic on it cannot overflow)
DIM_MAX = 1 << 20  # a descriptor dimension
SEQ_MAX = 1 << 16  # a sequence or window length
POSITION_MAX = 1e12  # |easting|, |northing| (metres) or a frame number read from a file


def number(value: Any, what: str, lo: float, hi: float, error: ErrorType = DatasetError,
           integer: bool = True) -> int | float:
    """``value`` as an int (``integer``) or float in ``[lo, hi]``; ``error`` naming ``what`` otherwise (the range
    said in words when it is only a sign: ``lo`` 1e-300 is "positive", ``lo`` -1e300 with ``hi`` 1e300 "finite")."""
    said = _range("integer" if integer else "number", lo, hi)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (integer and isinstance(value, float)
                                                                          and not value.is_integer()):
        raise error(f"{what} must be {said}, got {_short(value)}")
    try:
        finite = math.isfinite(value)
    except OverflowError:  # an int beyond any float
        finite = False
    if not finite or not lo <= value <= hi:
        raise error(f"{what} must be {said}, got {_short(value)}")
    return int(value) if integer else float(value)


def _range(noun: str, lo: float, hi: float) -> str:
    """``a positive number`` / ``a finite integer`` when the range is only a sign, else ``an integer in LO..HI``."""
    if hi >= 1e300 and 0 < lo <= 1e-300:
        return f"a positive {noun}"
    if hi >= 1e300 and lo <= -1e300:
        return f"a finite {noun}"
    return f"{'an' if noun == 'integer' else 'a'} {noun} in {lo}..{hi}"


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."
