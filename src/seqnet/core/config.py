"""One configuration style for every stage: small frozen dataclasses that validate themselves.

A stage's configuration is a ``@dataclasses.dataclass(frozen=True)`` deriving from :class:`Config`;
its defaults are its field defaults, ``__post_init__`` validates (and normalises) every field with
the ``check_*`` helpers below, and the mixin adds :meth:`Config.from_dict` (unknown keys are an
error naming the valid ones), :meth:`Config.replace` (``None`` means "keep") and
:meth:`Config.to_dict` (JSON-ready, written beside every run's outputs).
"""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, TypeVar

import numpy as np

from .errors import ConfigError

C = TypeVar("C", bound="Config")


class Config:
    """Mixin for frozen dataclass configurations (see the module docstring)."""

    RENAMED_KEYS: typing.ClassVar[Mapping[str, str]] = {}  # {earlier key: its name now}, read by from_dict

    @classmethod
    def from_dict(cls: type[C], values: Mapping[str, Any] | None = None) -> C:
        """Build from a mapping (e.g. a ``config.json``); nested configs may be given as mappings. A key under
        its earlier name (:attr:`RENAMED_KEYS`: files written by earlier versions) is read as its name now."""
        values = dict(values or {})
        for old, new in cls.RENAMED_KEYS.items():
            if old in values and new not in values:
                values[new] = values.pop(old)
        _reject_unknown(cls, values)
        nested = _nested_types(cls)
        for key, sub in nested.items():
            if isinstance(values.get(key), Mapping):
                values[key] = sub.from_dict(values[key])
        return cls(**values)  # type: ignore[call-arg]

    def replace(self: C, **changes: Any) -> C:
        """A copy with ``changes`` applied, ``None`` included (``conf.replace(target_precision=None)`` turns
        calibration off); nested configs accept a mapping of their own changes. Validation runs again on the
        result."""
        return self._changed(changes, keep_none=False)

    def merge(self: C, **changes: Any) -> C:
        """:meth:`replace`, but a ``None`` value keeps the current one: how the CLI lays the options given over
        a configuration (an option not given is None)."""
        return self._changed(changes, keep_none=True)

    def _changed(self: C, changes: Mapping[str, Any], keep_none: bool) -> C:
        _reject_unknown(type(self), changes)
        nested = _nested_types(type(self))
        out = {}
        for key, value in changes.items():
            if value is None and keep_none:
                continue
            if key in nested and isinstance(value, Mapping):
                value = getattr(self, key)._changed(value, keep_none)
            out[key] = value
        return dataclasses.replace(self, **out)  # type: ignore[type-var]

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (tuples become lists, nested configs dicts)."""
        return _jsonable(dataclasses.asdict(self))  # type: ignore[call-overload]

    def _set(self, name: str, value: Any) -> None:
        """Normalise a field inside ``__post_init__`` (the dataclass is frozen)."""
        object.__setattr__(self, name, value)


def _reject_unknown(cls: type, values: Mapping[str, Any]) -> None:
    valid = [f.name for f in dataclasses.fields(cls) if f.init]
    bad = [k for k in values if k not in valid]
    if bad:
        raise ConfigError(f"unknown {cls.__name__} key {bad[0]!r}; valid: {', '.join(valid)}")


def _nested_types(cls: type) -> dict[str, type[Config]]:
    hints = typing.get_type_hints(cls)
    return {k: t for k, t in hints.items() if isinstance(t, type) and issubclass(t, Config)}


def _jsonable(x: Any) -> Any:
    if isinstance(x, Mapping):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    return x


# ----------------------------------------------------------------------------- validators


def check_int(name: str, value: Any, minimum: int | None = None, maximum: int | None = None) -> int:
    """``value`` as an int within ``[minimum, maximum]``; bools and non-integers are refused."""
    ok = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
    if not ok or (minimum is not None and value < minimum) or (maximum is not None and value > maximum):
        rng = _range_text(minimum, maximum)
        raise ConfigError(f"{name} must be an integer{rng}, got {value!r}")
    return int(value)


def check_float(name: str, value: Any, minimum: float | None = None, maximum: float | None = None,
                strict: bool = False) -> float:
    """``value`` as a finite float ``>= minimum`` (``> minimum`` when ``strict``) and ``<= maximum``."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = math.nan
    if isinstance(value, (bool, str)) or not math.isfinite(v):
        raise ConfigError(f"{name} must be a finite number, got {value!r}")
    low_bad = minimum is not None and (v <= minimum if strict else v < minimum)
    if low_bad or (maximum is not None and v > maximum):
        op = ">" if strict else ">="
        rng = f" {op} {minimum:g}" if minimum is not None else ""
        rng += (" and" if rng else "") + (f" <= {maximum:g}" if maximum is not None else "")
        raise ConfigError(f"{name} must be a number{rng}, got {value!r}")
    return v


def check_choice(name: str, value: Any, choices: Iterable[str]) -> str:
    """``value`` if it is one of ``choices``, else :class:`ConfigError` listing them."""
    choices = list(choices)
    if not isinstance(value, str) or value not in choices:
        raise ConfigError(f"unknown {name} {value!r}; valid: {', '.join(choices)}")
    return value


def check_bool(name: str, value: Any) -> bool:
    """``value`` if it is a bool (numbers and strings are refused: ``"false"`` is truthy)."""
    if not isinstance(value, (bool, np.bool_)):
        raise ConfigError(f"{name} must be true or false, got {value!r}")
    return bool(value)


def check_ints(name: str, values: Any, minimum: int | None = None) -> tuple[int, ...]:
    """A non-empty sequence of integers ``>= minimum``, as a tuple."""
    if isinstance(values, (str, bytes)) or not isinstance(values, (Sequence, np.ndarray)) or len(values) == 0:
        raise ConfigError(f"{name} must be a non-empty list of integers{_range_text(minimum, None)}, got {values!r}")
    return tuple(check_int(name, v, minimum) for v in values)


def check_range(name: str, value: Any) -> tuple[int, int]:
    """A half-open index range ``(start, stop)`` with ``0 <= start < stop``."""
    try:
        a, b = (check_int(name, v, 0) for v in value)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"{name} must be a [start, stop] pair of integers, got {value!r}") from err
    if a >= b:
        raise ConfigError(f"{name} must satisfy start < stop, got {a}:{b}")
    return a, b


def _range_text(minimum: int | None, maximum: int | None) -> str:
    if minimum is not None and maximum is not None:
        return f" in {minimum}..{maximum}"
    if minimum is not None:
        return f" >= {minimum}"
    return f" <= {maximum}" if maximum is not None else ""
