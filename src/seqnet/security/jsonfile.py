"""Reading a JSON file from anywhere: bounded in size, strict, and every failure one line.

``dataset.json``, ``map.json``, provenance sidecars, run configurations and manifests are read here:
at most :data:`MAX_JSON` bytes, UTF-8, no ``NaN`` / ``Infinity`` (not JSON), integers of at most
4300 digits (Python's own limit), nesting as deep as the parser allows; anything else is ``error``
naming the file.
"""

from __future__ import annotations

import json
import os
from typing import Any

from ..core.errors import DatasetError
from .inputs import ErrorType, read_text

MAX_JSON = 64 << 20


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not valid JSON")


def parse_json(text: str, where: str, error: ErrorType = DatasetError) -> Any:
    """``text`` parsed as strict JSON; ``error`` naming ``where`` when it is not."""
    try:
        return json.loads(text, parse_constant=_no_constant)
    except (ValueError, RecursionError, TypeError) as e:  # JSONDecodeError, digit limits, nesting
        raise error(f"{where}: not valid JSON ({' '.join(str(e).split())[:200]})") from e


def read_json(path: str | os.PathLike[str], what: str = "JSON file", error: ErrorType = DatasetError,
              limit: int = MAX_JSON) -> Any:
    """The JSON value of a file of at most ``limit`` bytes (:func:`seqnet.security.inputs.read_text`)."""
    return parse_json(read_text(path, limit, what, error), str(path), error)


def read_json_object(path: str | os.PathLike[str], what: str = "JSON file", error: ErrorType = DatasetError,
                     limit: int = MAX_JSON) -> dict[str, Any]:
    """:func:`read_json` of a file that must hold a JSON object."""
    value = read_json(path, what, error, limit)
    if not isinstance(value, dict):
        raise error(f"{path}: must hold a JSON object, got {type(value).__name__}")
    return value
