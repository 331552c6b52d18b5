"""Progress bars: one tqdm bar per long loop, shown on a terminal and hidden in log files.

By default a bar is drawn only when stderr is a TTY (tqdm's ``disable=None``), so a log file never
collects ``\\r`` redraws. The CLI's ``--progress`` / ``--no-progress`` sets the mode for the
duration of a command with :func:`progress_mode` (a context variable: nothing process-wide).
"""

from __future__ import annotations

import contextlib
import contextvars
import weakref
from collections.abc import Iterable, Iterator
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from tqdm.auto import tqdm

_MODE: contextvars.ContextVar[bool | None] = contextvars.ContextVar("seqnet_progress", default=None)
_OPEN: weakref.WeakSet = weakref.WeakSet()  # bars made here and not closed yet (closed before an error line)


@contextlib.contextmanager
def progress_mode(enabled: bool | None) -> Iterator[None]:
    """Force bars on (True) or off (False), or back to automatic (None: only on a TTY), inside the block."""
    token = _MODE.set(enabled)
    try:
        yield
    finally:
        _MODE.reset(token)


def progress(iterable: Iterable[Any] | None = None, desc: str | None = None, total: int | None = None,
             unit: str = "it", min_total: int = 2, **kwargs: Any) -> tqdm:
    """A tqdm bar (cleared when done) following :func:`progress_mode`; hidden for fewer than
    ``min_total`` steps. Extra keyword arguments go to tqdm."""
    if total is None and iterable is not None and hasattr(iterable, "__len__"):
        total = len(iterable)  # type: ignore[arg-type]
    mode = _MODE.get()
    disable = (not mode) if mode is not None else None
    if total is not None and total < min_total:
        disable = True
    from tqdm.auto import tqdm  # on the first bar: a command that draws none (or its --help) never loads tqdm

    bar = tqdm(iterable, desc=desc, total=total, unit=unit, leave=False, disable=disable, dynamic_ncols=True,
               **kwargs)
    _OPEN.add(bar)
    return bar


def close_all() -> None:
    """Close (and so clear from the terminal) every bar still open, e.g. before printing an error."""
    for bar in list(_OPEN):
        with contextlib.suppress(Exception):
            bar.close()
