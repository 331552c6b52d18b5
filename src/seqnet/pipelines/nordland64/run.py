"""The Nordland64 stage: data → models → evaluation of the val and test ranges → report."""

from __future__ import annotations

import time
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

from ...core.log import logger
from ...core.stage import Written
from ...data.traverse import Dataset
from ...eval.evaluation import Evaluation
from ...eval.score import score
from ...metrics.recall import recall_curve
from ...report.guidance import learned_below_baseline, note_entries
from ...report.html import ReportConfig, write_html_report
from ...report.tables import format_markdown, ground_truth_text, markdown_notes, plot_pr_curves, plot_recall_curves
from ...security.files import write_json_atomic, write_text_atomic
from ...security.locks import locked
from ...security.text import shown
from ..descriptor_choice import descriptor_text
from ..outputs import check_outputs_of, write_outputs
from . import cache
from .config import Nordland64Config
from .data import SEASONS, SPLITS, build_dataset
from .models import train_models
from .select import choose_hvpr, descriptor_on_val
from .speed import variable_speed

if TYPE_CHECKING:
    from ...sequence.model import SeqNet

KIND = "benchmark nordland64"  # the command, as the output folder's record names it
OUTPUTS = ("results.json", "val_results.json", "results.md", "recall_at_k.png", "pr_curve.png", "report.html",
           "config.json")


def split_dataset(ds: Dataset, conf: Nordland64Config, split: str) -> Dataset:
    """One split, its query re-sampled at ``conf.query_speed`` (seeded per split) when set."""
    return variable_speed(ds.split(split), conf.query_speed, [conf.speed_seed, SPLITS.index(split)])


def evaluate_split(ds: Dataset, models: Mapping[str, SeqNet], conf: Nordland64Config, split: str) -> Evaluation:
    """Every benchmark method on one split (centred L-frame windows; ``hvpr-*`` re-rank with S_1)."""
    return score(split_dataset(ds, conf, split), conf.eval_config(), models)


def hvpr_on_val(ds: Dataset, models: Mapping[str, SeqNet], conf: Nordland64Config) -> tuple[Nordland64Config, list]:
    """``conf`` with the HVPR settings of ``conf.select`` chosen on the val range (:func:`.select.choose_hvpr`;
    the test range is never read), and the choices."""
    if not {"top_k", "fuse_top_k", "fuse_weight"} & set(conf.select):
        return conf, []
    conf, _, choices = choose_hvpr(split_dataset(ds, conf, "val"), models, conf, conf.eval_config())
    return conf, choices


def selection_notes(selection: Mapping[str, object]) -> list[str]:
    """The sentences saying what was chosen on val and why (empty: nothing was chosen)."""
    descriptor = selection.get("descriptor")
    return ([descriptor["reason"]] if isinstance(descriptor, dict) else []) + \
        [c["reason"] for c in selection.get("hvpr", [])]


def write_report(ev: Evaluation, val: Evaluation, conf: Nordland64Config, seconds: Mapping[str, float],
                 out: Path, selection: Mapping[str, object] | None = None, dim: int | None = None) -> None:
    """``results.json`` (eval schema + benchmark config and timings), ``val_results.json``,
    ``results.md`` (Table-I style, with AUC and R@100P; its headline names the descriptors: ``conf.describe``'s
    method and views, and their D ``dim``), ``recall_at_k.png`` (Recall@K, K = 1..20, test range) and
    ``pr_curve.png`` (precision–recall of every method, test range)."""
    ev.results["config"].update(benchmark=conf.to_dict(), timings_s=dict(seconds))
    ev.results["selection"] = dict(selection or {})
    below = learned_below_baseline(ev.results)
    ev.results["learned_below_baseline"] = note_entries(below)
    notes = selection_notes(selection or {})
    write_json_atomic(out / "results.json", ev.results)
    write_json_atomic(out / "val_results.json", val.results)
    curves = {m: recall_curve(r, ev.view(m).truth, 20) for m, r in ev.retrieved.items()}
    speed = "" if conf.query_speed is None else f", query at {conf.query_speed[0]:g}–{conf.query_speed[1]:g}× speed"
    title = f"Nordland64 test (L={conf.seq_len}{speed})"
    plot_recall_curves(curves, out / "recall_at_k.png", title=title)
    plot_pr_curves(ev.results["methods"], out / "pr_curve.png", title=title)
    first = next(iter(ev.results["methods"].values()))
    (a, b), (c, d) = conf.test_range, conf.val_range
    lines = [
        "# Nordland64 benchmark results", "",
        f"Reference summer, query winter; test places {a}:{b} ({first['queries']} queries with a full "
        f"L={conf.seq_len} window); {truth_note(ev.results['config'])}; descriptor "
        f"{descriptor_text(conf.describe, dim)}."
        + speed_note(conf), "",
        *(["Chosen on val (never on test): " + "; ".join(notes) + ".", ""] if notes else []),
        format_markdown(ev.results["methods"], ks=(1, 5, 20), results=ev.results),
        *([markdown_notes(below)] if below else []),
        f"Validation (places {c}:{d}, used to select epochs and settings), R@1: "
        + ", ".join(f"{m} {r['recall@1']:.3f}" for m, r in val.results["methods"].items()), "",
        "Timings (s): " + ", ".join(f"{k} {v:.1f}" for k, v in seconds.items()), "",
    ]
    write_text_atomic(out / "results.md", "\n".join(lines))


def truth_note(config: dict) -> str:
    """What counted as correct in ``results.md``'s header: the radius in frame steps, or explicit positives."""
    text = ground_truth_text(config)
    return text if config.get("ground_truth") == "explicit positives" else f"{text} (frame steps)"


def speed_note(conf: Nordland64Config) -> str:
    """The sentence of ``results.md`` on the query speed (empty at the filmed speed)."""
    if conf.query_speed is None:
        return ""
    a, b = conf.query_speed
    return (f" Query re-sampled at {a:g}–{b:g}× the reference speed (smooth seeded profile, seed "
            f"{conf.speed_seed}; frames dropped or repeated, positions kept).")


def report_config(data: str | Path, title: str) -> ReportConfig:
    """The HTML report settings of a nordland64 run: the gallery reads the winter (query) and summer
    (reference) images of the data folder ``data``."""
    return ReportConfig(title=title, query_images=str(Path(data) / SEASONS[1]),
                        ref_images=str(Path(data) / SEASONS[0]))


def main(conf: Nordland64Config, data: str | Path, out: str | Path, overwrite: bool = False) -> Written:
    """Run the benchmark (hloc style) on the nordland64 folder ``data``; writes everything to ``out``
    (descriptor and model cache, :data:`OUTPUTS`) and returns the path of ``results.json``.

    The outputs replace only what an earlier run of the benchmark wrote there (refused before any work
    otherwise, unless ``overwrite``) and appear together (:mod:`seqnet.pipelines.outputs`); the cache is
    reused only whole (:mod:`.cache`)."""
    out = Path(out)
    with locked(out):
        check_outputs_of(out, OUTPUTS, KIND, "nordland64 results", overwrite)
        cache.check_owned(out, (*cache.CHOICE, *cache.DESCRIPTORS, *cache.MODELS), overwrite)
        t0 = time.perf_counter()
        seconds: dict[str, float] = {}
        conf, descriptor = descriptor_on_val(conf, data, out, overwrite)
        if descriptor is not None:
            seconds["choose_descriptor"] = round(time.perf_counter() - t0, 2)
        ds, flipped = build_dataset(data, conf, out, overwrite)
        seconds["descriptors"] = round(time.perf_counter() - t0 - seconds.get("choose_descriptor", 0.0), 2)
        logger.info("nordland64: %d places, D=%d; train %s, val %s, test %s", len(ds.query), ds.query.dim,
                    conf.train_range, conf.val_range, conf.test_range)
        models, train_s = train_models(ds, conf, out, flipped, overwrite=overwrite)
        seconds.update({f"train_{k}": v for k, v in train_s.items()})
        t1 = time.perf_counter()
        conf, choices = hvpr_on_val(ds, models, conf)
        selection = {"descriptor": descriptor, "hvpr": [c.to_dict() for c in choices]}
        val = evaluate_split(ds, models, conf, "val")
        ev = evaluate_split(ds, models, conf, "test")
        seconds["evaluation"] = round(time.perf_counter() - t1, 2)
        seconds["total"] = round(time.perf_counter() - t0, 2)

        def write(tmp: Path) -> None:
            write_report(ev, val, conf, seconds, tmp, selection, ds.query.dim)
            write_html_report(ev, split_dataset(ds, conf, "test"), tmp / "report.html",
                              report_config(data, f"Nordland64 benchmark, test places {conf.test_range[0]}:"
                                                  f"{conf.test_range[1]}"))
            write_json_atomic(tmp / "config.json", {**conf.to_dict(), "data": str(data)})

        write_outputs(out, KIND, "nordland64 results", write, overwrite)
        logger.info("nordland64 done in %.0f s: %s", seconds["total"], shown(out / "results.md"))
    return Written(out / "results.json", ev.results)
