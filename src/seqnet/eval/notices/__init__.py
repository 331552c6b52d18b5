"""What an evaluation says beside its numbers when the user probably meant something else (one line each, logged as a
warning and kept in the results' ``warnings``): ground truth that looks shifted (:func:`shift_notice`), a
``--radius`` that explicit positives make moot (:func:`radius_ignored`), no split named test (:func:`split_note`), a
method that retrieved one reference per query (:func:`one_retrieved`), a video's query clock off the reference's
(:func:`video_clock_note`), a K of ``--ks`` that scores every query (:func:`trivial_ks`; a default K:
:func:`default_ks_note`), a model whose epoch was chosen on the evaluated queries (:func:`selection_leakage`) or
trained on them (:func:`leakages`), all of these for another stage that scores queries (:func:`scored_notices`), an
R@1 over few queries (:func:`few_queries`), and HVPR settings chosen on training queries (:func:`training_choice`)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...core.log import counted, logger
from ...methods.checks import kept_count, named_test_split, overlapping, queries_span, role_label
from ...methods.trained import chosen_range, free_hint, train_range, used_ranges
from ...security.text import shown
from ..calibrated import calibration_on_test
from ..config import EvalConfig
from ..evaluation import Evaluation
from .shift import shift_notice  # noqa: F401 - a notices name, used by eval, maps

if TYPE_CHECKING:
    from ...data.traverse import Dataset
    from ...sequence.model import SeqNet


FEW_QUERIES = 30  # below this many scored queries, R@1 moves by more than 0.033 per query: a note says so


def add_warnings(ev: Evaluation, lines: Iterable[str | None]) -> None:
    """Log each line of ``lines`` (None: nothing to say) as a warning and keep it in ``ev.results["warnings"]``."""
    for said in say(lines):
        ev.results["warnings"] = [*ev.results.get("warnings", []), said]


def say(lines: Iterable[str | None]) -> list[str]:
    """Log each line of ``lines`` (None: nothing to say) as a warning; the lines said."""
    out = [line for line in lines if line]
    for line in out:
        logger.warning("%s", shown(line))
    return out


def scored_notices(given: str | None, ds: Dataset, split: str, models: Mapping[str, SeqNet], dataset: str | Path,
                   calibrate_split: str | None = None) -> list[str]:
    """What eval says about the queries a run scores on split ``split`` of the dataset ``ds`` (directory
    ``dataset``; ``given``: the ``--split`` given, None for the default): no split named test
    (:func:`split_note`), queries a model chose its epoch on (:func:`selection_leakage`) or was trained on
    (:func:`seqnet.methods.checks.leakage`; ``calibrate_split``: the split a threshold is calibrated on, too, and
    whether it is the test split, :func:`seqnet.eval.calibrated.calibration_on_test`). For
    the stages that score queries as eval does (``seqnet localize --dataset``)."""
    from ...methods.checks import leakage

    lines = [split_note(given, list(ds.splits), len(ds.split(split).query)),
             *selection_leakage(models, dataset, ds, split), *leakage(models, dataset, ds, split)]
    if calibrate_split is not None:
        lines += [calibration_on_test(ds, calibrate_split, split),
                  *leakage(models, dataset, ds, calibrate_split, calibration=True, evaluated=split)]
    return [line for line in lines if line]


def leakages(models: Mapping[str, SeqNet], dataset: str | Path, ds: Dataset, split: str,
             conf: EvalConfig) -> tuple[list[str], list[str]]:
    """:func:`seqnet.methods.checks.leakage` of the evaluated ``split`` and (:func:`calibration_leakage`) of the
    calibration split, counting the queries ``conf`` keeps (``--resample-every``): the two lists, each read once."""
    from ...methods.checks import leakage

    return (leakage(models, dataset, ds, split, every=conf.query_every),
            calibration_leakage(models, dataset, ds, split, conf))


def calibration_leakage(models: Mapping[str, SeqNet], dataset: str | Path, ds: Dataset, split: str,
                        conf: EvalConfig) -> list[str]:
    """The :func:`seqnet.methods.checks.leakage` lines of the calibration split (with ``conf.target_precision``):
    its queries that the models were trained on."""
    from ...methods.checks import leakage

    if conf.target_precision is None:
        return []
    return leakage(models, dataset, ds, conf.calibrate_split, calibration=True, evaluated=split,
                   every=conf.query_every)


def one_retrieved(ev: Evaluation) -> str | None:
    """What to say when some methods retrieved one reference per query (``--ks 1``): their confidence cannot
    compare the top-1 with another place, so their PR entries are empty."""
    names = [n for n, r in ev.retrieved.items() if r.shape[1] < 2]
    if not names:
        return None
    return (f"{', '.join(names)} retrieved one reference per query (the largest K of --ks is 1): the confidence "
            "compares the top-1 with the best other place retrieved, so no PR curve, AUC, R@100P or "
            "confidence_for_precision is given for them; add a larger K (e.g. --ks 1,20; "
            "EvalConfig(ks=(1, 20)) in Python)")


def video_clock_note(ev: Evaluation) -> str | None:
    """A ``dataset from-video`` query track a constant time off the reference's, seen in the top-1 answers of a
    method (the first that shows it: :func:`seqnet.sources.tracks.offset.dataset_offset_note`); else None."""
    from ...sources.tracks.offset import dataset_offset_note

    notes = (dataset_offset_note(ev.dataset, ev.view(n).q_items, ev.view(n).r_items, r[:, 0])
             for n, r in ev.retrieved.items() if r.ndim == 2 and r.shape[1])
    return next((note for note in notes if note), None)


def few_queries(scored: Mapping[str, tuple[int, float]]) -> str | None:
    """Why R@1 over few queries says little: ``scored`` maps each method to ``(queries scored, R@1)``; below
    :data:`FEW_QUERIES` of them, one query moves R@1 by 1/n, and each R@1's 95% (Wilson) interval is given."""
    counts = [n for n, _ in scored.values() if n > 0]
    if not counts or min(counts) >= FEW_QUERIES:
        return None
    n, most = min(counts), max(counts)
    spans = ", ".join(f"{name} {r:.3f} in {lo:.3f}-{hi:.3f}" for name, (k, r) in scored.items() if k > 0
                      for lo, hi in [wilson(r, k)])
    many = f"{n} quer{'y' if n == 1 else 'ies'}" if most == n else f"{n} to {most} queries (by method)"
    return (f"only {many} scored: one query changes R@1 by {'' if most == n else 'up to '}1/{n} = {1 / n:.3f}; 95% "
            f"intervals of R@1 (Wilson): {spans}; hint: a larger split or range (--split) to compare methods")


def few_queries_note(results: Mapping[str, Any]) -> str | None:
    """:func:`few_queries` of an evaluation's ``results`` (its methods' scored queries and R@1)."""
    return few_queries({name: (r["queries"], r["recall@1"]) for name, r in (results.get("methods") or {}).items()
                        if isinstance(r.get("recall@1"), float) and isinstance(r.get("queries"), int)})


def wilson(p: float, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval ``(low, high)`` of a proportion ``p`` observed over ``n`` > 0 trials."""
    centre, half = p + z * z / (2 * n), z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    denom = 1 + z * z / n
    return max(0.0, (centre - half) / denom), min(1.0, (centre + half) / denom)


def radius_ignored(radius: float | None, explicit: bool) -> str | None:
    """Why ``--radius`` changed nothing: explicit positives decide what is correct."""
    if radius is None or not explicit:
        return None
    return (f"--radius does not change Recall@K with explicit positives (they decide what is correct); use "
            f"--extra-radius {radius:g} to also count references within {radius:g} of a positive")


def split_note(given: str | None, splits: Sequence[str], n_queries: int) -> str | None:
    """What is scored when no split was given, the dataset has splits and none is named ``test``: every query,
    the training ones too."""
    if given is not None or not splits or "test" in splits:
        return None
    test = named_test_split(splits)
    hint = f"--split {test}" if test else f"--split NAME (one of {', '.join(splits)}) or a range A:B"
    return f"no split named test (splits: {', '.join(splits)}); scoring all {n_queries} queries — hint: {hint}"


def trivial_ks(ev: Evaluation, ks: Sequence[int]) -> str | None:
    """Which K of ``ks`` (given with ``--ks``: not the default Ks, whose R@100 a small dataset makes trivial every
    time: a warning on every such run, with a hint about a choice the user did not make; :func:`default_ks_note`
    says those columns as a note instead) are at least the references a method indexes (its R@K is 1 for every
    query with a positive: says nothing), and which HVPR shortlists hold every reference
    (:func:`whole_shortlists`), in one line."""
    trivial = trivial_columns(ev, ks) if tuple(ks) != EvalConfig().ks else {}
    said = ", ".join(f"R@{k} (K >= the {n} references indexed)" for k, n in sorted(trivial.items()))
    lines = [f"{said}: every query with a positive counts as found, trivially; hint: a K below the references"
             if trivial else None, whole_shortlists(ev)]
    return "; ".join(line for line in lines if line) or None


def trivial_columns(ev: Evaluation, ks: Sequence[int]) -> dict[int, int]:
    """Each K of ``ks`` that is at least the references some method indexes, with the fewest such references."""
    trivial: dict[int, int] = {}
    for name in ev.retrieved:
        n = len(ev.view(name).r_items)
        for k in ks:
            if k >= n:
                trivial[k] = min(n, trivial.get(k, n))
    return trivial


def default_ks_note(ev: Evaluation, ks: Sequence[int]) -> str | None:
    """The note (printed after the table, not a warning: :func:`trivial_ks` says why) for the default Ks' columns
    that are at least the references a method indexes: they read 1.000 for every query with a positive."""
    if tuple(ks) != EvalConfig().ks:
        return None
    trivial = trivial_columns(ev, ks)
    if not trivial:
        return None
    cols = ", ".join(f"R@{k}" for k in sorted(trivial))
    fewest = min(len(ev.view(name).r_items) for name in ev.retrieved)
    below = ",".join(str(k) for k in ks if k < fewest)
    hint = f"--ks {below} leaves them out" if below else "--ks with Ks below the references"
    one = len(trivial) == 1
    return (f"{cols} {'is' if one else 'are'} trivial here (K >= the {min(trivial.values())} references indexed): "
            f"every query with a positive counts as found, so {'that column says' if one else 'those columns say'} "
            f"nothing (the default Ks; {hint})")


def whole_shortlists(ev: Evaluation) -> str | None:
    """The HVPR methods whose shortlist size K is at least the references they index: the shortlist is every
    reference, so the method re-ranks them all (its label's ``top-K`` is not a shortlist)."""
    whole = {}
    for name, entry in ev.results.get("methods", {}).items():
        k = (entry.get("method") or {}).get("top_k")
        if name in ev.retrieved and isinstance(k, int) and k >= (n := len(ev.view(name).r_items)):
            whole[name] = (k, n, "--fuse-top-k" if "fuse_weight" in (entry.get("method") or {}) else "--top-k")
    if not whole:
        return None
    said = ", ".join(f"{name} (K {k} >= the {n} references indexed)" for name, (k, n, _) in whole.items())
    flags = " / ".join(sorted({flag for *_, flag in whole.values()}, reverse=True))
    return (f"{said}: the shortlist holds every reference, so it re-ranks them all; hint: {flags} below the "
            "references for a shortlist")


def selection_leakage(models: Mapping[str, SeqNet], dataset: str | Path, ds: Dataset, split: str,
                      every: int | None = None) -> list[str]:
    """One line per model whose epoch was chosen on queries of ``dataset`` that the evaluated ``split`` holds (the
    val range its checkpoint recorded: :func:`seqnet.methods.trained.chosen_range`), with a hint naming queries free
    of every model's training and epoch-selection ones, never the split in use. ``every``: the split's queries are
    re-sampled (``--resample-every``), and only the kept ones are counted."""

    a, b = ds.ranges(split)["query"]
    out, ranges = [], None
    for role, t, (val, (va, vb)), both in overlapping(models, lambda m: chosen_range(m, dataset, ds), a, b, every,
                                                      span=lambda found: found[1]):
        ranges = ranges or used_ranges(models, dataset, ds)  # for the hint: read once, when there is one
        trained, picked = ranges
        hint = ("choosing the epoch on the test split makes its test numbers optimistic; hint: train with "
                "--val-split val" if val == named_test_split(ds.splits) else
                f"hint: {free_hint(ds, trained, picked, split)}")
        n = counted(kept_count(a, a, b, every), "evaluated query", "evaluated queries")
        out.append(f"{both} of the {n} ({split!r}, {queries_span(a, b, every)}) are queries the {role_label(role)} "
                   f"model {t['checkpoint']} chose its epoch on ({val!r}, {va}:{vb}), so its results on them are "
                   f"optimistic: {hint}")
    return out


def training_choice(models: Mapping[str, SeqNet], dataset: str | Path, ds: Dataset,
                    choices: Sequence[Any]) -> str | None:
    """The line for HVPR settings (``choices``: :class:`seqnet.eval.select.Choice`) chosen on val queries of ``ds``
    (directory ``dataset``) that are training queries of the models (the range each checkpoint recorded:
    :func:`seqnet.methods.trained.train_range`): the setting that suits what a model memorised wins, as a
    threshold calibrated on them promises too much; None when none is, or nothing was chosen."""
    rng = ds.ranges("val")
    if not choices or rng is None:
        return None
    a, b = rng["query"]
    said = [f"{both} are training queries of the {role_label(role)} model {t['checkpoint']} ({lo}:{hi})"
            for role, t, (lo, hi), both in overlapping(models, lambda m: train_range(m, dataset, ds), a, b)]
    if not said:
        return None
    return (f"HVPR settings of {', '.join(c.method for c in choices)} chosen on the val split ({a}:{b}, {b - a} "
            f"queries), of which {'; '.join(said)}: the setting that suits what a model memorised wins (hint: give "
            "--top-k / --fuse-top-k / --fuse-weight yourself, or rebuild the dataset with a val split apart from "
            "the training queries)")
