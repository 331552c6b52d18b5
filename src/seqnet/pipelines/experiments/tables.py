"""``seqnet experiment tables``: every table of the paper (and its t-SNE figure) in one run — each
experiment into ``OUT/table-…/`` (``OUT/tsne/``) with one shared cache (default ``OUT``) — and ``OUT/results.md``, the
paper's tables beside ours one after the other, in the paper's order.

Each experiment runs with its defaults and the benchmark settings given here, exactly as its own
command would (``seqnet experiment table-1 …`` gives the same ``OUT/table-1``).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

from ...core.config import Config, check_choice
from ...core.utils import logger
from ...security.files import write_json_atomic, write_text_atomic
from ..nordland64 import Nordland64Config

FIGURES = ("tsne",)  # the paper's figures reproduced besides its tables


@dataclasses.dataclass(frozen=True)
class TablesConfig(Config):
    """Settings of the whole set: the benchmark's, and which tables (``I``, ``II``, ``III``, ``S1``, ``S2``,
    ``S3``) and figures (``tsne``) to make."""

    benchmark: Nordland64Config = Nordland64Config()
    tables: tuple[str, ...] = ("I", "II", "III", "S1", "S2", "S3", "tsne")

    def __post_init__(self) -> None:
        valid = (*_by_table(), *FIGURES)
        self._set("tables", tuple(dict.fromkeys(check_choice("paper table", t, valid) for t in self.tables)))


def _by_table() -> dict[str, str]:
    """``{paper table: experiment name}``."""
    from . import EXPERIMENTS

    return {e.paper: name for name, e in EXPERIMENTS.items() if e.paper}


def _run_one(key: str, conf: TablesConfig, data: str | Path, out: Path, cache: Path) -> tuple[str, Path]:
    """Run the experiment of table ``key`` (or figure) with its defaults; its sub-folder and ``results.md``."""
    from . import EXPERIMENTS

    name = _by_table().get(key, key)
    exp = EXPERIMENTS[name]
    sub = out / (exp.alias or name)
    logger.info("paper tables: %s (%s) into %s", key, name, sub)
    exp.start(exp.config().replace(benchmark=conf.benchmark) if exp.data else exp.config(), sub, data, cache)
    return name, sub


def main(conf: TablesConfig, data: str | Path, out: str | Path, cache: str | Path | None = None) -> Path:
    """Run every table of ``conf``; writes ``OUT/<table>/`` per table, ``results.md`` (every table's Markdown
    in order), ``results.json`` (where each is, seconds) and ``config.json``; returns ``results.json``."""
    out = Path(out)
    cache = Path(cache) if cache else out
    parts, index = ["# The SeqNet paper's tables on Nordland64, beside the paper's\n"], {}
    for key in conf.tables:
        t0 = time.perf_counter()
        name, sub = _run_one(key, conf, data, out, cache)
        index[key] = {"experiment": name, "folder": sub.name, "seconds": round(time.perf_counter() - t0, 1)}
        body = (sub / "results.md").read_text(encoding="utf-8").replace("\n# ", "\n## ")
        title, rest = body.split("\n", 1)  # its own title becomes the section's
        parts.append(f"\n## {key}: {title.lstrip('# ')} (`seqnet experiment {sub.name}`, {sub.name}/)\n\n"
                     + rest.lstrip("\n"))
    write_text_atomic(out / "results.md", "".join(parts))
    results: dict[str, Any] = {"experiment": "tables", "tables": index}
    write_json_atomic(out / "config.json", {"experiment": "tables", **conf.to_dict(), "data": str(data),
                                            "cache": str(cache)})
    return write_json_atomic(out / "results.json", results)
