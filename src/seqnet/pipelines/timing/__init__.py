"""``seqnet benchmark timing``: the paper's compute-time table measured here, and its sweep over map sizes.

Modules: :mod:`.config` (:class:`TimingConfig`), :mod:`.synth` (synthetic maps with structure),
:mod:`.queries`, :mod:`.measure` / :mod:`.measure_hvpr` (what is timed and counted), :mod:`.worker`
(one fresh process per map build and per map timing, for honest peak RSS), :mod:`.run` (the stage),
:mod:`.report` (``results.md``, ``timing.png``). See docs/scale.md.
"""

from .config import BIG_SIZES, TimingConfig
from .run import main

__all__ = ["BIG_SIZES", "TimingConfig", "main"]
