"""What the experiments share: the benchmark's descriptors and models (cached, reused across
experiments through a cache folder), evaluations of its splits, tables, and the files every
experiment writes (``results.json``, ``results.md``, its figure, ``report.html``, ``config.json``).

Cache layout (the same as a benchmark run's output, so ``--cache out/nordland64`` reuses a
benchmark's descriptors and models): ``CACHE/dataset``, ``CACHE/flip_train.npy``,
``CACHE/models``, ``CACHE/runs`` and the cache's record ``CACHE/.seqnet-cache.json``
(:mod:`seqnet.pipelines.nordland64.cache`: what is reused, only whole); models of other settings
(seeds, descriptors) live in sub-folders named by the experiment (:func:`prepare`). An experiment's
outputs replace only its own earlier ones and appear together (:mod:`seqnet.pipelines.outputs`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import html
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ...core.errors import ConfigError
from ...data.traverse import Dataset
from ...eval.config import EvalConfig
from ...eval.evaluation import Evaluation
from ...eval.score import score
from ...methods.grammar import parse_method
from ...report.guidance import learned_below_baseline, note_entries
from ...report.html import ReportConfig, evaluation_sections, figure_section, render_html, rows_as_text
from ...report.markup import Section, table_html
from ...report.tables import ground_truth_text, mark_markdown_rows, markdown_notes, save_figure
from ...security.files import write_json_atomic, write_text_atomic
from ...security.locks import locked
from ..nordland64 import Nordland64Config, build_dataset, train_models
from ..nordland64 import cache as nordland_cache
from ..nordland64.config import DESCRIBE
from ..nordland64.data import SEASONS
from ..nordland64.run import report_config
from ..outputs import check_outputs_of
from ..outputs import write_outputs as write_folder

if TYPE_CHECKING:
    from ...sequence.model import SeqNet


@dataclasses.dataclass
class Prepared:
    """The dataset (every place in use, raw descriptors), its trained models, and the splits evaluated:
    the benchmark's (val, test), or those a user's dataset defines (:func:`prepare_dataset`)."""

    ds: Dataset
    models: dict[str, SeqNet]
    seconds: dict[str, float]
    splits: tuple[str, ...] = ("val", "test")
    name: str = "Nordland64"

    @property
    def main(self) -> str:
        """The split the report and the side-by-side tables show (the last: test when there is one)."""
        return self.splits[-1]

    def runnable(self, methods: Sequence[str]) -> tuple[str, ...]:
        """The ``methods`` whose models are here (a user's dataset may come with S_1 only, or none)."""
        return tuple(m for m in methods if parse_method(m).models() <= set(self.models))


def prepare_dataset(dataset: str | Path, models: Sequence[str | Path], seq_len: int) -> Prepared:
    """A user's seqnet dataset directory and its models (``--dataset DIR --model CKPT``) in place of the
    benchmark's: the splits evaluated are its ``val`` and ``test`` when it defines them, else ``all``."""
    from ...data.io import load_dataset
    from ...sequence.checkpoints import load_models

    ds = load_dataset(dataset)
    splits = tuple(s for s in ("val", "test") if s in ds.splits) or ("all",)
    return Prepared(ds, load_models(models, seq_len=seq_len), {}, splits, ds.name or Path(dataset).name)


def source(conf: Nordland64Config, data: str | Path | None, cache: Path, dataset: str | Path | None,
           models: Sequence[str | Path], overwrite: bool = False) -> Prepared:
    """The benchmark's data and models (``data``: the nordland64 folder) or a user's (``dataset``, ``models``)."""
    check_source(data, dataset)
    return prepare(conf, data, cache, overwrite=overwrite) if dataset is None else \
        prepare_dataset(dataset, models, conf.seq_len)


def check_source(data: str | Path | None, dataset: str | Path | None) -> None:
    """Exactly one of the nordland64 folder and a user's dataset."""
    if (data is None) == (dataset is None):
        raise ConfigError("give the nordland64 folder (--data) or a seqnet dataset with its models (--dataset, "
                          "--model), one of the two")


def descriptor_cache(conf: Nordland64Config, cache: Path) -> Path:
    """Where the descriptors (and models) of ``conf`` are cached: ``cache`` for the benchmark's
    descriptor settings, ``cache/descriptors/METHOD`` for any other (so that a shared cache never
    replaces the benchmark's descriptors)."""
    return cache if conf.describe == DESCRIBE else cache / "descriptors" / conf.describe.method


def check_cache(conf: Nordland64Config, cache: Path, models_sub: str | None = None, overwrite: bool = False) -> None:
    """Before any work: the entries of the cache that :func:`prepare` may replace were made by the cache
    (:func:`seqnet.pipelines.nordland64.cache.check_owned`)."""
    root = descriptor_cache(conf, cache)
    nordland_cache.check_owned(root, nordland_cache.DESCRIPTORS, overwrite)
    nordland_cache.check_owned(root / models_sub if models_sub else root, nordland_cache.MODELS, overwrite)


def prepare(conf: Nordland64Config, data: str | Path, cache: Path, models_sub: str | None = None,
            overwrite: bool = False) -> Prepared:
    """Describe and train as the benchmark does with the settings ``conf``; descriptors cached in
    :func:`descriptor_cache`, models there too (in its sub-folder ``models_sub`` when given), each reused
    only whole (:mod:`seqnet.pipelines.nordland64.cache`)."""
    check_cache(conf, cache, models_sub, overwrite)
    root = descriptor_cache(conf, cache)
    t0 = time.perf_counter()
    ds, flipped = build_dataset(data, conf, root, overwrite)
    seconds = {"descriptors": round(time.perf_counter() - t0, 2)}
    models, train_s = train_models(ds, conf, root / models_sub if models_sub else root, flipped,
                                   nordland_cache.unit_files(root, "descriptors"), overwrite)
    seconds.update({f"train_{k}": v for k, v in train_s.items()})
    return Prepared(ds, models, seconds)


def evaluate_splits(p: Prepared, conf: EvalConfig, transform: Any = None) -> dict[str, Evaluation]:
    """``conf``'s methods on each split of ``p`` (``transform(ds)`` applied to the split first, if given)."""
    out = {}
    for split in p.splits:
        ds = p.ds.split(split)
        out[split] = score(transform(ds) if transform else ds, conf, p.models)
    return out


@contextlib.contextmanager
def locked_dirs(out: Path, cache: Path) -> Iterator[None]:
    """Lock the output folder and, when it is another one, the cache folder."""
    with locked(out):
        if cache.resolve() == out.resolve():
            yield
        else:
            with locked(cache):
                yield


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """A Markdown table (floats with 3 decimals)."""
    text = rows_as_text(rows)
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    return "\n".join([*lines, *("| " + " | ".join(r) + " |" for r in text)]) + "\n"


def table_section(id_: str, title: str, tables: Mapping[str, tuple[Sequence[str], Sequence[Sequence[Any]]]],
                  text: str = "") -> Section:
    """A report section of titled tables, after an optional paragraph."""
    body = f"<p>{html.escape(text)}</p>" if text else ""
    for caption, (header, rows) in tables.items():
        body += f"<h3>{html.escape(caption)}</h3>" + table_html(header, rows_as_text(rows))
    return Section(id_, title, body)


@dataclasses.dataclass
class Outputs:
    """What an experiment writes (see :func:`write_outputs`)."""

    name: str
    results: dict[str, Any]
    markdown: str
    figure: Any  # a matplotlib figure, saved as NAME.png
    sections: list[Section]  # the experiment's own report sections (tables, figure)
    evaluation: tuple[Evaluation, Dataset] | None = None  # an evaluation (and its split) whose report follows
    evaluations: Mapping[str, Evaluation] | None = None  # every evaluation, by label (None: ``evaluation``'s)


def output_names(name: str, *extra: str) -> tuple[str, ...]:
    """What experiment ``name`` (its figure's name) writes into its output folder."""
    return ("results.json", "results.md", f"{name}.png", "report.html", "config.json", *extra)


def kind_of(name: str) -> str:
    """The command of experiment ``name`` (its figure's name), as the output folder's record names it."""
    return f"experiment {name.replace('_', '-')}"


def check_experiment(out: Path, name: str, overwrite: bool = False, extra: Sequence[str] = ()) -> None:
    """Before any work: what experiment ``name`` writes into ``out`` replaces only its own earlier outputs
    (:func:`seqnet.pipelines.outputs.check_outputs_of`)."""
    check_outputs_of(out, output_names(name, *extra), kind_of(name), "experiment's outputs", overwrite)


def write_outputs(o: Outputs, conf: Any, data: str | Path, out: Path, title: str, overwrite: bool = False,
                  more: Callable[[Path], Any] | None = None) -> Path:
    """:func:`write_files` (and ``more(folder)``, other outputs) into ``out`` as one new version
    (:func:`seqnet.pipelines.outputs.write_outputs`); returns the path of ``results.json``."""

    def write(tmp: Path) -> None:
        write_files(o, conf, data, tmp, title)
        if more is not None:
            more(tmp)

    write_folder(out, kind_of(o.name), "experiment's outputs", write, overwrite)
    return out / "results.json"


def write_files(o: Outputs, conf: Any, data: str | Path, out: Path, title: str) -> Path:
    """``results.json``, ``results.md``, ``NAME.png``, ``report.html`` and ``config.json`` (the resolved
    configuration, the data folder and the provenance of the descriptors) in ``out``; returns the
    path of ``results.json``."""
    markdown = with_notes(o)
    write_json_atomic(out / "results.json", o.results)
    write_text_atomic(out / "results.md", markdown)
    png = save_figure(o.figure, out / f"{o.name}.png")
    sections = [*o.sections, figure_section("figure", f"Figure ({png.name})", o.figure)]
    if o.evaluation is not None:
        ev, ds = o.evaluation
        images = (Path(data) / SEASONS[0]).is_dir()  # the nordland64 folder: the gallery shows its frames
        sections += evaluation_sections(ev, ds, report_config(data, title) if images else ReportConfig(title=title))
    write_text_atomic(out / "report.html", render_html(title, sections))
    write_json_atomic(out / "config.json", {"experiment": o.name, **conf.to_dict(), "data": str(data),
                                            "figure": png.name, "provenance": o.results.get("provenance")})
    return out / "results.json"


def with_notes(o: Outputs) -> str:
    """The learned methods below their model-free counterparts in each evaluation of ``o``
    (:mod:`seqnet.report.guidance`): added to ``o.results`` as ``learned_below_baseline`` (eval's entries, each
    with the ``evaluation`` it is about; none without evaluations) and to ``o.markdown``, returned: the rows of
    flagged methods marked, the notes listed under the tables."""
    evs = o.evaluations if o.evaluations is not None else \
        {"report": o.evaluation[0]} if o.evaluation is not None else {}
    if not evs:
        return o.markdown
    entries: list[dict[str, Any]] = []
    marks: dict[str, dict[str, list[str]]] = {}  # learned method -> baseline -> the evaluations
    said = []
    for label, ev in evs.items():
        notes = learned_below_baseline(ev.results)
        entries += note_entries(notes, label)
        for n in notes:
            marks.setdefault(n.learned, {}).setdefault(n.baseline, []).append(label)
        said += [markdown_notes(notes, label)] if notes else []
    o.results["learned_below_baseline"] = entries
    flagged = {name: "learned, below model-free " + ", ".join(f"{b} ({', '.join(labels)})" for b, labels in by.items())
               for name, by in marks.items()}
    return mark_markdown_rows(o.markdown, flagged) + "".join("\n" + text for text in said)


def truth_text(ev: Evaluation) -> str:
    """What counted as correct in an experiment's header: the radius, or the dataset's explicit positives."""
    return ground_truth_text(ev.results["config"])


def recall_table(evs: Mapping[str, Evaluation], methods: Sequence[str], k: int = 1) -> list[list[Any]]:
    """Rows ``[method, R@k of each evaluation]`` (None where a method was not run)."""
    return [[m, *(e.results["methods"].get(m, {}).get(f"recall@{k}") for e in evs.values())] for m in methods]


def queries_of(ev: Evaluation) -> int:
    """The number of queries an evaluation ranked (those with a full window; the same for every method)."""
    return next(iter(ev.results["methods"].values()))["queries"]


def recall_at_1(evs: Mapping[str, Evaluation], methods: Sequence[str]) -> dict[str, dict[str, float]]:
    """``{evaluation: {method: R@1}}``."""
    return {k: {m: e.results["methods"][m]["recall@1"] for m in methods} for k, e in evs.items()}


def summary(ev: Evaluation) -> dict[str, Any]:
    """The per-method results of an evaluation without its config (for an experiment's results.json)."""
    return {m: {k: v for k, v in r.items() if k != "method"} for m, r in ev.results["methods"].items()}
