"""Longer sequences on Nordland64 (the SeqNet paper's L_m = 5 / 10 / 20 table).

HVPR keeps its S_5 shortlist (L = 5) and re-ranks with SeqMatch on S_1 over L_m frames; it is
compared with the graph matcher (GISM-style, :mod:`seqnet.matching.graph`) over the whole map and as the
HVPR re-ranker, and with S_1 + SeqMatch, all at the same L_m, on the val and test ranges (the query
re-sampled when ``conf.query_speed`` is set). Items are the frames whose centred L_m window fits the
range, so a longer L_m evaluates a few fewer queries (reported).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ...core.config import check_ints
from ...core.log import logger
from ...eval.score import score
from ...methods.grammar import parse_method
from ...security.files import write_json_atomic, write_text_atomic
from ...security.locks import locked
from .config import Nordland64Config
from .data import build_dataset
from .models import train_models
from .run import speed_note, split_dataset

LONGER_METHODS = ("hvpr", "s1+seqmatch", "s1+graph", "hvpr-seqnet:s1+graph")
LONGER_SPLITS = ("val", "test")


def longer_sequences(conf: Nordland64Config, data: str | Path, out: str | Path, lengths: Sequence[int] = (5, 10, 20),
                     methods: Sequence[str] = LONGER_METHODS) -> Path:
    """Evaluate ``methods`` with L = ``conf.seq_len`` and each L_m of ``lengths`` on the val and test
    ranges of the nordland64 folder ``data``; ``out`` holds the descriptor and model caches (shared
    with ``seqnet benchmark nordland64 --out``), ``longer.json`` and ``longer.md``. Returns the JSON path."""
    lengths = check_ints("lengths", tuple(lengths), 1)
    conf = conf.merge(methods=tuple(methods))
    out = Path(out)
    with locked(out):
        t0 = time.perf_counter()
        ds, flipped = build_dataset(data, conf, out)
        models, _ = train_models(ds, conf, out, flipped)
        results: dict[str, dict[str, Any]] = {}
        for split in LONGER_SPLITS:
            sub = split_dataset(ds, conf, split)
            for lm in lengths:
                ev = score(sub, conf.eval_config().merge(methods=tuple(methods), match_len=lm), models)
                results.setdefault(split, {})[str(lm)] = ev.results["methods"]
                logger.info("longer sequences: %s L_m=%d done", split, lm)
        record = {"results": results, "lengths": list(lengths), "methods": list(methods),
                  "config": conf.to_dict(), "data": str(data), "seconds": round(time.perf_counter() - t0, 2)}
        write_json_atomic(out / "longer.json", record)
        write_text_atomic(out / "longer.md", longer_markdown(record, conf))
    return out / "longer.json"


def longer_markdown(record: dict[str, Any], conf: Nordland64Config) -> str:
    """R@1 and AUC tables (rows: methods; columns: L_m) for each split of a :func:`longer_sequences` record."""
    lengths = [str(lm) for lm in record["lengths"]]
    top_k = conf.eval_config().shortlist_size(parse_method("hvpr"))
    lines = ["# Nordland64: longer sequences", "",
             f"L = {conf.seq_len} (S_L shortlist of HVPR, top {top_k}); L_m = sequence-matcher length; "
             f"radius {conf.radius:g}." + speed_note(conf), ""]
    for split, by_len in record["results"].items():
        a, b = getattr(conf, f"{split}_range")
        for key, title in (("recall@1", "R@1"), ("auc", "AUC")):
            lines += [f"**{split} {a}:{b}, {title}**", "", "| method | " + " | ".join(f"L_m={lm}" for lm in lengths)
                      + " |", "|---|" + "---|" * len(lengths)]
            for m in record["methods"]:
                lines.append(f"| {m} | " + " | ".join(f"{by_len[lm][m][key]:.3f}" for lm in lengths) + " |")
            lines.append("")
        queries = ", ".join(f"L_m={lm}: {next(iter(by_len[lm].values()))['queries']}" for lm in lengths)
        lines += [f"Queries ({split}): {queries}.", ""]
    return "\n".join(lines)
