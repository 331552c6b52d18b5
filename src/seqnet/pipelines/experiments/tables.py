"""``seqnet experiment tables``: every table of the paper (and its t-SNE figure) in one run — each
experiment into ``OUT/table-…/`` (``OUT/tsne/``) with one shared cache (default ``OUT``) — and ``OUT/results.md``, the
paper's tables beside ours one after the other, in the paper's order.

Each experiment runs with its defaults and the benchmark settings given here, exactly as its own
command would (``seqnet experiment table-1 …`` gives the same ``OUT/table-1``). The whole run holds
``OUT``'s lock; every output is checked before any work, and the top-level files appear together.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

from ...core.config import Config, check_choice
from ...core.log import logger
from ...security.files import write_json_atomic, write_text_atomic
from ...security.locks import locked
from ...security.text import shown
from ..nordland64 import Nordland64Config
from ..outputs import check_outputs_of, write_outputs
from .common import check_experiment
from .registry import PAPER_EXPERIMENTS

FIGURES = ("tsne",)  # the paper's figures reproduced besides its tables
KIND = "experiment tables"  # the command, as the output folder's record names it
OUTPUTS = ("results.md", "results.json", "config.json")


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
    return {e.paper: name for name, e in PAPER_EXPERIMENTS.items() if e.paper}


def _planned(key: str, conf: TablesConfig) -> tuple[str, Any, Config, str]:
    """The experiment of table ``key`` (or figure): its name, entry, settings and sub-folder."""
    name = _by_table().get(key, key)
    exp = PAPER_EXPERIMENTS[name]
    return name, exp, exp.config().merge(benchmark=conf.benchmark) if exp.data else exp.config(), exp.alias or name


def _check_all(conf: TablesConfig, out: Path, overwrite: bool) -> None:
    """Before any work: every experiment's outputs in its sub-folder and the top-level files replace only what
    these experiments wrote."""
    check_outputs_of(out, OUTPUTS, KIND, "paper tables", overwrite)
    for key in conf.tables:
        name, _, sub_conf, folder = _planned(key, conf)
        extra = {"compute-time": ("timing",), "descriptors": getattr(sub_conf, "descriptors", ())}.get(name, ())
        check_experiment(out / folder, name.replace("-", "_"), overwrite, extra)


def main(conf: TablesConfig, data: str | Path, out: str | Path, cache: str | Path | None = None,
         overwrite: bool = False) -> Path:
    """Run every table of ``conf``; writes ``OUT/<table>/`` per table, ``results.md`` (every table's Markdown
    in order), ``results.json`` (where each is, seconds) and ``config.json``; returns ``results.json``."""
    out = Path(out)
    cache = Path(cache) if cache else out
    parts, index = ["# The SeqNet paper's tables on Nordland64, beside the paper's\n"], {}
    with locked(out):
        _check_all(conf, out, overwrite)
        for key in conf.tables:
            t0 = time.perf_counter()
            name, exp, sub_conf, folder = _planned(key, conf)
            logger.info("paper tables: %s (%s) into %s", key, name, shown(out / folder))
            exp.start(sub_conf, out / folder, data, cache, overwrite=overwrite)
            index[key] = {"experiment": name, "folder": folder, "seconds": round(time.perf_counter() - t0, 1)}
            body = (out / folder / "results.md").read_text(encoding="utf-8").replace("\n# ", "\n## ")
            title, rest = body.split("\n", 1)  # its own title becomes the section's
            parts.append(f"\n## {key}: {title.lstrip('# ')} (`seqnet experiment {folder}`, {folder}/)\n\n"
                         + rest.lstrip("\n"))
        results: dict[str, Any] = {"experiment": "tables", "tables": index}

        def write(tmp: Path) -> None:
            write_text_atomic(tmp / "results.md", "".join(parts))
            write_json_atomic(tmp / "config.json", {"experiment": "tables", **conf.to_dict(), "data": str(data),
                                                    "cache": str(cache)})
            write_json_atomic(tmp / "results.json", results)

        write_outputs(out, KIND, "paper tables", write, overwrite)
    return out / "results.json"
