"""Heavy modules (torch) imported on first use, so that ``seqnet <command> --help`` and argument errors
answer without loading them.

``torch = lazy_module("torch")`` gives a stand-in module: the first attribute read imports the real one
and copies its namespace into the stand-in, so later reads cost what a plain module attribute costs.
A module already imported is returned as it is. Nothing at a module's top level may read an attribute
of a lazy module (a type alias, a dtype table, a base class, a decorator): that would import it on the
spot. :func:`no_grad` is the decorator form of ``torch.no_grad()`` that waits for the first call.
"""

from __future__ import annotations

import functools
import importlib
import inspect
import sys
import types
from collections.abc import Callable
from typing import Any, TypeVar

Fn = TypeVar("Fn", bound=Callable[..., Any])


class LazyModule(types.ModuleType):
    """A module imported when one of its attributes is first read."""

    def __getattr__(self, attr: str) -> Any:
        module = importlib.import_module(self.__name__)
        self.__dict__.update(module.__dict__)  # later reads find the attribute without coming here
        return getattr(module, attr)


def lazy_module(name: str) -> types.ModuleType:
    """The module ``name`` if it is imported already, else a :class:`LazyModule` standing in for it."""
    module = sys.modules.get(name)
    return module if module is not None else LazyModule(name)


def no_grad(fn: Fn) -> Fn:
    """``fn`` run under ``torch.no_grad()`` (torch imported at the first call, not at decoration)."""
    if inspect.isgeneratorfunction(fn):
        raise TypeError(f"no_grad: {fn.__qualname__} is a generator function (use torch.no_grad() inside it)")
    torch = lazy_module("torch")

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with torch.no_grad():
            return fn(*args, **kwargs)

    return wrapper  # type: ignore[return-value]
