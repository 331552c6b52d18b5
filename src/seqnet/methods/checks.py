"""The checks of an evaluation that need no descriptors: models, lengths and provenance before any work, and
the flag on models evaluated on their own training queries (:func:`leakage`)."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..core.errors import ConfigError, WindowsTooLongError
from ..core.log import counted, logger, ordinal
from ..core.provenance import check_same
from ..data.traverse import Dataset
from ..security.text import shown
from ..sequence.descriptors import SEQUENCE_DESCRIPTORS
from ..sequence.windows import longest_option
from .grammar import Method
from .route import REVERSED_BELOW, reversed_route, route_direction, trivial_truth  # noqa: F401
from .trained import (  # noqa: F401 - named_test_split: a methods.checks name, used by others
    MAX_RECORD_TEXT,
    free_hint,
    named_test_split,
    train_range,
    used_ranges,
)

if TYPE_CHECKING:
    from ..sequence.model import SeqNet



def check_inputs(ds: Dataset, methods: list[Method], models: Mapping[str, SeqNet], length: int, match_len: int,
                 allow_mismatch: bool = False, longest: int | None = None) -> None:
    """Every check that does not need descriptors: models present and fitting (D, provenance, L), lengths
    (L of the sequence descriptors, L_m of the matchers; ``longest``: the longest window the methods use, by
    default max(L, L_m): 1 when every method is single-frame)."""
    check_methods(methods, models, length)
    check_provenance(ds, models, length, allow_mismatch)
    for side, t in (("query", ds.query), ("reference", ds.reference)):
        check_windows_fit(max(length, match_len) if longest is None else longest, len(t),
                          f"the {side} traverse of dataset {ds.name!r}", longest_option(length, match_len))
    check_memory(ds, methods, models)


def check_memory(ds: Dataset, methods: list[Method], models: Mapping[str, SeqNet]) -> None:
    """Refuse, before describing, an evaluation whose estimate exceeds the available memory (one line, exit 1):
    the models, every sequence descriptor of the query side, the reference's up to the spill size each, and
    the search blocks (:func:`seqnet.core.memory.described_bytes`)."""
    from ..core.memmaps import limit
    from ..core.memory import check_fits, described_bytes, gib, model_bytes, workspace_bytes

    names = dict.fromkeys(d for m in methods for d in m.descriptors())
    dims = descriptor_dims(names, models, ds.query.dim)
    need = model_bytes(models.values()) + described_bytes(len(ds.query), len(ds.reference), dims, limit("SPILL"))
    check_fits(need + workspace_bytes(len(ds.query), len(ds.reference)),
               f"evaluating {len(methods)} method(s) on {len(ds.query)} query frames (descriptors "
               f"{', '.join(names)}: {gib(described_bytes(len(ds.query), 0, dims, 0))} on the query side)",
               "evaluate a smaller --split or fewer methods, or describe with fewer dimensions (--dim, PCA) "
               "or a smaller S_L / S_1 (--out-dims)")


def check_windows_fit(longest: int, n: int, what: str, option: str = "--seq-len") -> None:
    """The windows (``longest`` = max(L, L_m) frames, set by ``option``) fit a traverse of ``n`` frames."""
    if longest > n:
        name = "match_len" if option == "--match-len" else "seq_len"
        raise WindowsTooLongError(f"{name}={longest} is longer than {what} ({n} frame{'s' * (n != 1)}); use a shorter "
                          f"{option} or a longer split")


def check_methods(methods: list[Method], models: Mapping[str, SeqNet], length: int) -> None:
    """Each method's models are given and its descriptors accept the sequence length L."""
    for m in methods:
        missing = m.models() - set(models)
        if missing:
            need = " and ".join("an S_1 model (--rerank-model CKPT; models={'s1': load_model(CKPT)} in Python)"
                                if r == "s1" else "an S_L model (--shortlist-model CKPT; models={'seqnet': "
                                "load_model(CKPT)} in Python)" for r in sorted(missing))
            free = _model_free(m) or (f"raw+{m.matcher}" if m.matcher else "single" if m.single_frame else "delta")
            hint = f"; or the model-free {free!r}"
            raise ConfigError(f"method {m.name!r} needs {need}{hint}")
        if m.min_len() > length:
            raise ConfigError(f"method {m.name!r} uses Delta descriptors, which need seq_len >= {m.min_len()} "
                              f"(got {length}); use a longer --seq-len or other methods")


def _model_free(m: Method) -> str | None:
    """The model-free variant of an HVPR method whose re-ranking needs S_1 (``hvpr-single`` → its frames raw)."""
    if m.kind != "hvpr" or m.shortlist is None or m.frames != "s1":
        return None
    if SEQUENCE_DESCRIPTORS[m.shortlist].model is not None:
        return None
    return f"hvpr-{m.shortlist}:raw+{m.matcher}"


def check_provenance(ds: Dataset, models: Mapping[str, SeqNet], length: int, allow: bool = False) -> None:
    """Reference and query descriptors made alike; each model used on the descriptors (D, provenance)
    and the sequence length L it was trained with (unless ``allow``)."""
    check_same(ds.reference.provenance, ds.query.provenance, "the reference descriptors", "the query descriptors",
               allow or accepted_mismatch(ds))
    check_models(models, ds.query.dim, ds.reference.provenance, f"dataset {ds.name!r}", length, allow)


def accepted_mismatch(ds: Dataset) -> bool:
    """The dataset was built with ``--allow-mismatch`` over reference and query descriptors made differently
    (recorded in dataset.json): later commands on it need not repeat the flag."""
    return bool(ds.extra.get("allow_mismatch"))


def check_models(models: Mapping[str, SeqNet], dim: int, provenance: dict | None, where: str, length: int,
                 allow: bool = False, use: str = "is evaluated with") -> None:
    """Each model reads ``dim``-D descriptors made as ``provenance`` (those of ``where``, e.g. ``dataset
    'x'``; with ``allow`` a provenance mismatch only warns) and, for S_L, windows of L = ``length`` >= its
    width w: its temporal pooling (the mean over the ``L - w + 1`` outputs of the convolution) makes S_L
    valid at any L >= w, so another L than the trained one is one info line (:func:`model_lengths` records
    it), and L < w is refused."""
    for role, model in models.items():
        name = "S_1" if role == "s1" else f"S_{model.seq_len}"
        check_role(role, model)
        if model.in_dims != dim:
            raise ConfigError(f"the {role} model ({name}) expects D={model.in_dims} descriptors "
                              f"but the dataset has D={dim}{_trained_on_hint(model, where)}")
        check_same(model.provenance, provenance, f"the descriptors the {name} model was trained on",
                   f"the descriptors of {where}", allow)
        if role == "seqnet" and model.seq_len != length:
            check_window_len(model, length, use)


def check_role(role: str, model: SeqNet) -> None:
    """A model given under the other role (``{"seqnet": S_1, "s1": S_5}``) is refused naming the role and the fix
    (it failed later with 'SeqNet with w=3 needs windows of >= 3 frames, got 1')."""
    given = getattr(model, "role", role)
    if role in ("seqnet", "s1") and given != role:
        kind = "an S_1 (L=1, w=1)" if given == "s1" else f"an S_{model.seq_len} (L={model.seq_len}, w={model.w})"
        want = "an S_1" if role == "s1" else "an S_L (L > 1)"
        raise ConfigError(f"models[{role!r}] is {kind}: the {role!r} role takes {want}; did you swap the roles? "
                          f"(hint: models[{given!r}] takes it; load_models([...]) assigns the roles from the "
                          "checkpoints)")


def _trained_on_hint(model: SeqNet, where: str) -> str:
    """The hint naming the dataset a checkpoint was trained on (e.g. the ``DS-pca32`` that ``train --pca 32``
    wrote beside ``DS``), when it records one (``--dataset`` named when ``where`` is a dataset); else empty."""
    path = (getattr(model, "trained_on", None) or {}).get("dataset")
    if not path:
        return ""
    use = f"--dataset {shown(path)}" if where.startswith("dataset") else "a map built from that dataset"
    return f"; hint: it was trained on the dataset {shown(path)}: {use}"


def check_window_len(model: SeqNet, length: int, use: str = "is evaluated with") -> None:
    """An S_L model trained at L_d = ``model.seq_len`` with width w applied at ``length``: refused when
    ``length < w``, else one info line."""
    if length < model.w:
        raise ConfigError(f"the S_L model (trained with L={model.seq_len}, w={model.w}) {use} L={length}, "
                          f"shorter than its convolution width w={model.w}; hint: --seq-len L with "
                          f"L >= {model.w} (e.g. --seq-len {model.seq_len}, the trained length)")
    logger.info("the S_L model was trained with L=%d (w=%d) and %s L=%d: valid, its temporal pooling averages "
                "the L - w + 1 = %d outputs of the convolution", model.seq_len, model.w, use, length,
                length - model.w + 1)


def model_lengths(models: Mapping[str, SeqNet]) -> dict[str, int]:
    """The sequence length each model was trained with, by role (``model_seq_len`` of the results, beside
    the ``seq_len`` they are applied at)."""
    return {role: int(m.seq_len) for role, m in sorted(models.items())}


def kept_count(a: int, lo: int, hi: int, every: int | None = None) -> int:
    """How many of the queries ``a, a + every, ...`` of a split starting at ``a`` (``--resample-every``; None: every
    query) lie in ``lo:hi``."""
    n = every or 1
    lo, hi = max(lo, a), max(hi, a)
    return max(0, -((a - hi) // n) - -((a - lo) // n))  # ceil((hi - a) / n) - ceil((lo - a) / n)


def queries_span(a: int, b: int, every: int | None = None) -> str:
    """The evaluated queries of ``a:b`` in words: ``a:b``, or ``every 2nd of a:b`` when re-sampled."""
    return f"every {ordinal(every)} of {a}:{b}" if every and every > 1 else f"{a}:{b}"


def leakage(models: Mapping[str, SeqNet], dataset: str | Path, ds: Dataset, split: str,
            calibration: bool = False, evaluated: str | None = None, every: int | None = None) -> list[str]:
    """One line per model trained on queries of ``dataset`` that the evaluated ``split`` (``calibration``: the
    split a confidence threshold is calibrated on, for the evaluation of ``evaluated``) contains too: the train
    range its checkpoint recorded wherever the same descriptors are read (:func:`seqnet.methods.trained.train_range`),
    and a hint naming queries free of every model's training and epoch-selection ones
    (:func:`seqnet.methods.trained.free_hint`), never the split in use. ``every``: the split's queries are
    re-sampled (``--resample-every``), and only the kept ones are counted."""
    a, b = ds.ranges(split)["query"]
    out, ranges = [], None
    for role, t, rng, both in overlapping(models, lambda m: train_range(m, dataset, ds), a, b, every):
        ranges = ranges or used_ranges(models, dataset, ds)  # for the hint: read once, when there is one
        trained, chosen = ranges
        now = ds.ranges(t["split"])
        when = "" if now is not None and tuple(now["query"]) == rng else " when it was trained"
        if calibration:
            avoid = [ds.ranges(evaluated)["query"]] if ds.ranges(evaluated) is not None else []
            tail = ("a threshold calibrated on them is optimistic, its promise does not hold (hint: "
                    f"{free_hint(ds, trained, chosen, split, '--calibrate-split', avoid)})")
        else:
            tail = f"its results on them are not a test (hint: {free_hint(ds, trained, chosen, split)})"
        what = "calibration" if calibration else "evaluated"
        out.append(f"{both} of the {counted(kept_count(a, a, b, every), what + ' query', what + ' queries')} "
                   f"({split!r}, {queries_span(a, b, every)}) are training queries of the {role_label(role)} model "
                   f"{t['checkpoint']} ({t['split']!r}{when}, {rng[0]}:{rng[1]}): {tail}")
    return out


def overlapping(models: Mapping[str, Any], found_of: Callable[[Any], Any], a: int, b: int, every: int | None = None,
                span: Callable[[Any], tuple[int, int]] = lambda found: found) -> Iterator[tuple[str, dict, Any, int]]:
    """``(role, record, found, count)`` per model (in role order) with a training record
    (:func:`training_record`) whose ``found_of(model)`` (a recorded range, or what holds one: ``span(found)``)
    shares ``count`` > 0 queries with ``a:b`` (``every``: only the re-sampled ones counted, :func:`kept_count`)."""
    for role, m in sorted(models.items()):
        t = training_record(m)
        found = found_of(m) if t is not None else None
        if found is None:
            continue
        lo, hi = span(found)
        both = kept_count(a, max(a, lo), min(b, hi), every)
        if both:
            yield role, t, found, both


def role_label(role: str) -> str:
    """``S_1`` for the role ``s1``, else ``S_L`` (the sequence model)."""
    return "S_1" if role == "s1" else "S_L"


def training_record(model: Any) -> dict[str, str] | None:
    """A model's ``trained_on`` (``dataset``, ``split``, ``checkpoint``, read from its checkpoint file) when
    every field is usable text; None otherwise (an unusable record is ignored, with a debug line)."""
    t = getattr(model, "trained_on", None)
    if not isinstance(t, Mapping) or not t.get("dataset"):
        return None
    fields = {k: t.get(k) for k in ("dataset", "split", "checkpoint")}
    if all(isinstance(v, str) and v and len(v) <= MAX_RECORD_TEXT and "\x00" not in v for v in fields.values()):
        return fields
    logger.debug("ignoring the training record of %.200r: its dataset, split and checkpoint are not all text "
                 "(%.200r)", fields.get("checkpoint"), fields)
    return None


def descriptor_dims(names: Iterable[str], models: Mapping[str, SeqNet], dim: int) -> list[int]:
    """D' of each sequence descriptor ``names`` on ``dim``-D frames (a model's output size, else ``dim``)."""
    return [models[r].out_dims if (r := SEQUENCE_DESCRIPTORS[d].model) and r in models else dim for d in names]


def check_resident(reference: Any, method: Method, models: Mapping[str, SeqNet]) -> None:
    """Refuse, before describing, a localiser whose reference (kept resident: searched every frame) cannot
    fit: a map's files, or every descriptor of the method over a reference traverse, with the models."""
    from ..core.memory import check_fits, described_bytes, gib, model_bytes, workspace_bytes

    if reference.frame_indices:
        return  # a distance matrix, already read
    held = getattr(reference, "nbytes", None)  # a map: its memory-mapped files
    if held is None:
        held = described_bytes(0, len(reference.positions), descriptor_dims(method.descriptors(), models,
                                                                            reference.input_dim), 1 << 62)
    check_fits(held + model_bytes(models.values()) + workspace_bytes(1, len(reference.positions)),
               f"localising against {reference.name!r} (kept in memory: {gib(held)})",
               "a map with a compressed index and float16 frames (seqnet index build --index ivf-pq --dtype "
               "float16), or fewer dimensions (--dim, PCA, --out-dims)")
