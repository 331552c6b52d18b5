"""``seqnet experiment splits`` (the paper's supplementary Table S1, "Data Splits"): the reference /
query sizes of the benchmark's train, val and test splits beside the paper's four datasets, and a
figure of where each split lies along the route (the splits do not overlap: a gap of places
separates them, as the paper's splits are geographically disjoint).

Only the descriptors are needed (made or read from the cache); nothing is trained.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ...core.config import Config
from ...data.traverse import Dataset
from ...report.paper import TABLE_S1, PaperRow, side_by_side
from ...report.tables import method_colours, new_figure
from ..nordland64 import Nordland64Config, build_dataset
from ..nordland64.cache import DESCRIPTORS, check_owned
from ..nordland64.data import SPLITS
from .common import Outputs, check_experiment, descriptor_cache, locked_dirs, table_section, write_outputs


@dataclasses.dataclass(frozen=True)
class SplitsConfig(Config):
    """Settings of the splits table: the benchmark's (its ranges and descriptors)."""

    benchmark: Nordland64Config = Nordland64Config()


def split_sizes(ds: Dataset) -> dict[str, dict[str, object]]:
    """``{split: {"reference": n, "query": n, "places": [a, b]}}`` of every split of ``ds`` (places: the
    half-open range of reference rows, offset by the dataset's first place)."""
    first = int(ds.extra.get("first_place", 0))
    out = {}
    for split in SPLITS:
        rng = ds.ranges(split)
        (a, b), (c, d) = rng["reference"], rng["query"]
        out[split] = {"reference": b - a, "query": d - c, "places": [first + a, first + b]}
    return out


def main(conf: SplitsConfig, data: str | Path, out: str | Path, cache: str | Path | None = None,
         overwrite: bool = False) -> Path:
    """Write ``results.json``, ``results.md``, ``splits.png``, ``report.html`` and ``config.json`` to ``out``."""
    out = Path(out)
    cache = Path(cache) if cache else out
    with locked_dirs(out, cache):
        check_experiment(out, "splits", overwrite)
        root = descriptor_cache(conf.benchmark, cache)
        check_owned(root, DESCRIPTORS, overwrite)
        ds, _ = build_dataset(data, conf.benchmark, root, overwrite)
        sizes = split_sizes(ds)

        def cell(row: PaperRow, _: int) -> str:
            return f"{sizes[row.method]['reference']} / {sizes[row.method]['query']}"

        flip = " The train split is used twice more in training (mirrored images), and both directions " \
               "(winter → summer, summer → winter)." if conf.benchmark.flip and conf.benchmark.symmetric else ""
        md = ("# Data splits (paper: Table S1), Nordland64\n\nReference (summer) / query (winter) frames; one "
              f"frame in ten of the clean list, 64×32 (NRK, CC BY).{flip}\n\n"
              + side_by_side(TABLE_S1, ("Nordland64",), cell))
        results = {"experiment": "splits", "paper_table": TABLE_S1.key, "sizes": sizes,
                   "provenance": ds.reference.provenance}
        header = ["split", "reference", "query", "places"]
        rows = [[s, v["reference"], v["query"], "{}:{}".format(*v["places"])] for s, v in sizes.items()]
        o = Outputs("splits", results, md, splits_figure(sizes),
                    [table_section("experiment", "Data splits (Table S1)", {"Sizes": (header, rows)})])
        return write_outputs(o, conf, data, out, "Experiment: data splits (paper Table S1)", overwrite)


def splits_figure(sizes: dict[str, dict[str, object]]) -> object:
    """Where each split lies along the route (place ranges), with its size."""
    fig, ax = new_figure(8, 2.2)
    for (split, v), colour in zip(sizes.items(), method_colours(len(sizes)), strict=True):
        a, b = v["places"]
        ax.barh(0, b - a, left=a, color=colour, label=f"{split}: {v['reference']} / {v['query']}")
    ax.set_yticks([])
    ax.set_xlabel("place (clean-list frame index)")
    ax.legend(fontsize=8, ncol=3, loc="upper center", bbox_to_anchor=(0.5, -0.45))
    ax.set_title("Splits along the route (reference / query frames)")
    return fig
