"""``seqnet benchmark timing``: the paper's compute-time table measured here, and its sweep over map sizes.

Modules: :mod:`.config` (:class:`TimingConfig`), :mod:`.synth` (synthetic maps with structure),
:mod:`.queries`, :mod:`.measure` / :mod:`.hvpr` (what is timed and counted), :mod:`.worker`
(one fresh process per map build and per map timing, for honest peak RSS), :mod:`.run` (the stage),
:mod:`.report` (``results.md``, ``timing.png``). See docs/scale.md.
"""

from typing import Any

from .config import BIG_SIZES, TimingConfig

__all__ = ["BIG_SIZES", "TimingConfig", "main"]


def __getattr__(name: str) -> Any:  # PEP 562: the stage (torch) loads when it runs, not with its config
    if name == "main":
        from .run import main

        return main
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
