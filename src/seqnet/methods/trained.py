"""What a model's checkpoint says of the queries it was trained and validated on, held against the data a command
reads: whether they are the same descriptors (:func:`same_data`: the recorded hashes of the descriptor files, else
their provenance and query names, else the dataset's path), the model's training queries (:func:`train_range`), and
a query range free of every model's training and epoch-selection queries to name in a hint (:func:`free_hint`).

A checkpoint written since training recorded its train range (``train_queries``) is held to that range wherever
the same descriptors are read (another path, a dataset rebuilt with new splits); an older one to the train split
of the dataset at the path it recorded, as read now."""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..data.io import recorded_digests

if TYPE_CHECKING:
    from ..data.traverse import Dataset

MIN_FREE = 20  # queries: a free range shorter than this is not worth naming in a hint


def descriptor_digests(path: str | Path | None) -> dict[str, str] | None:
    """The hashes seqnet recorded for the descriptor files of the dataset directory ``path`` (``checksums`` of its
    ``dataset.json``): ``{"reference/descriptors.npy": "SIZE:HASH", ...}``; None when none are recorded."""
    if path is None:
        return None
    out = {name: f"{entry.get('size')}:{entry.get('full') or entry.get('sample')}"
           for name, entry in recorded_digests(path).items()
           if isinstance(name, str) and isinstance(entry, Mapping)
           and name.rsplit("/", 1)[-1].startswith("descriptors.")}
    return out or None


def names_digest(names: Sequence[str] | None) -> str | None:
    """``"N:HASH"`` of the ``N`` image names of a traverse, in order (None without names): what identifies the
    frames behind its indices."""
    if not names:
        return None
    h = hashlib.sha256("\n".join(str(n) for n in names).encode("utf-8", "surrogateescape")).hexdigest()[:16]
    return f"{len(names)}:{h}"


def recorded_range(value: Any) -> tuple[int, int] | None:
    """``(a, b)`` of a range a checkpoint recorded as ``[a, b]`` (0 <= a < b, integers); None otherwise."""
    if isinstance(value, list | tuple) and len(value) == 2 and all(type(v) is int and v >= 0 for v in value) \
            and value[0] < value[1]:
        return int(value[0]), int(value[1])
    return None


def same_path(a: str | Path | None, b: str | Path) -> bool:
    """Whether ``a`` and ``b`` name the same file or folder (False when ``a`` is None or cannot be resolved)."""
    try:
        return a is not None and Path(a).resolve() == Path(b).resolve()
    except (OSError, ValueError, RuntimeError, TypeError):  # a record from a file: any type
        return False


def named_test_split(splits: Iterable[str]) -> str | None:
    """The split that is the test split: ``test``, else one named so in another case (``Test``); None."""
    splits = list(splits)
    return "test" if "test" in splits else next((s for s in splits if s.lower() == "test"), None)


MAX_RECORD_TEXT = 4096


def same_data(model: Any, dataset: str | Path, ds: Dataset) -> bool:
    """Whether ``ds`` (the dataset directory ``dataset``) holds the descriptors ``model`` was trained on, frame for
    frame: its checkpoint's descriptor hashes equal those recorded now; else the same provenance and query names
    (the same images described the same way: a rebuild whose descriptors differ in the last bits, as a GPU
    describer's or another thread count's do, is the same data); else, with no hashes on one side, the same
    dataset path."""
    t = getattr(model, "trained_on", None)
    if not isinstance(t, Mapping):
        return False
    then, now = t.get("dataset_digests"), descriptor_digests(dataset)
    hashed = isinstance(then, Mapping) and bool(then) and bool(now)
    if hashed and dict(then) == now:
        return True
    names, here = t.get("query_names"), names_digest(ds.query.names)
    prov, prov_now = getattr(model, "provenance", None), ds.query.provenance
    if isinstance(names, str) and here and isinstance(prov, Mapping) and isinstance(prov_now, Mapping):
        return names == here and prov.get("id") is not None and prov.get("id") == prov_now.get("id")
    return not hashed and same_path(t.get("dataset"), dataset)


def holds_training_data(model: Any, dataset: str | Path, ds: Dataset) -> bool:
    """Whether ``ds`` (directory ``dataset``) holds the data ``model`` was trained on: the same descriptors
    (:func:`same_data`) for a checkpoint that recorded its train range, the same path for an older one."""
    t = getattr(model, "trained_on", None)
    if not isinstance(t, Mapping):
        return False
    if recorded_range(t.get("train_queries")) is not None:
        return same_data(model, dataset, ds)
    return same_path(t.get("dataset"), dataset)


def train_range(model: Any, dataset: str | Path, ds: Dataset) -> tuple[int, int] | None:
    """The query range ``[a, b)`` of ``ds`` that ``model`` was trained on: the range its checkpoint recorded when
    ``ds`` holds the same descriptors (:func:`same_data`); for a checkpoint that recorded none, its train split in
    ``ds`` when ``dataset`` is the path it recorded. None when unknown or another dataset."""
    if not holds_training_data(model, dataset, ds):
        return None
    t = model.trained_on
    recorded = recorded_range(t.get("train_queries"))
    if recorded is not None:
        return recorded
    rng = ds.ranges(t["split"]) if isinstance(t.get("split"), str) else None
    return None if rng is None else tuple(rng["query"])


def chosen_range(model: Any, dataset: str | Path, ds: Dataset) -> tuple[str, tuple[int, int]] | None:
    """The split ``model`` chose its epoch on and its query range in ``ds`` (directory ``dataset``, holding the data
    it was trained on: :func:`holds_training_data`), as its checkpoint records them (``val_split``,
    ``val_queries``: a checkpoint copied out of its run folder says it too); for a checkpoint written before
    training recorded the range, that split's range in ``ds``; for one without a val split, the ``config.json``
    beside it (a run directory). None when unknown, not validated or another dataset."""
    if not holds_training_data(model, dataset, ds):
        return None
    t = model.trained_on
    val = t.get("val_split")
    if not isinstance(val, str) or not val or len(val) > MAX_RECORD_TEXT:
        return _run_config_range(t, ds)
    if val.lower() == "none":
        return None
    q = recorded_range(t.get("val_queries"))
    if q is not None:
        return val, q
    rng = ds.ranges(val)
    return None if rng is None else (val, tuple(rng["query"]))


def _run_config_range(t: Mapping[str, Any], ds: Dataset) -> tuple[str, tuple[int, int]] | None:
    """The val split and its query range from the ``config.json`` beside the checkpoint (a run directory)."""
    from ..core.errors import SeqnetError
    from ..security.jsonfile import read_json_object

    if not isinstance(t.get("checkpoint"), str):
        return None
    path = Path(t["checkpoint"]).parent / "config.json"
    try:
        cfg = read_json_object(path, "run configuration") if path.is_file() else {}
    except (SeqnetError, OSError):
        return None
    val = cfg.get("val_split")
    if not isinstance(val, str) or val.lower() == "none" or cfg.get("dataset_path") != t.get("dataset"):
        return None
    rng = ds.ranges(val)
    return None if rng is None else (val, tuple(rng["query"]))


def used_ranges(models: Mapping[str, Any], dataset: str | Path,
                ds: Dataset) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
    """The query ranges of ``ds`` the ``models`` were trained on, and those they chose their epoch on."""
    trained = [r for m in models.values() if (r := train_range(m, dataset, ds)) is not None]
    chosen = [c[1] for m in models.values() if (c := chosen_range(m, dataset, ds)) is not None]
    return trained, chosen


def _gaps(taken: Iterable[tuple[int, int]], n: int) -> list[tuple[int, int]]:
    """The ranges of ``[0, n)`` outside every range of ``taken``, longest first (then the earliest)."""
    out, at = [], 0
    for a, b in sorted(taken):
        if a > at:
            out.append((at, min(a, n)))
        at = max(at, b)
    if at < n:
        out.append((at, n))
    return sorted([g for g in out if g[1] > g[0]], key=lambda g: (g[0] - g[1], g[0]))


def _free(ds: Dataset, taken: list[tuple[int, int]], used: str, avoid: Sequence[tuple[int, int]]) -> str | None:
    """A named split of ``ds`` (test first) apart from ``taken`` and ``avoid`` and other than ``used``, else the
    longest range apart from them of :data:`MIN_FREE` queries or more (``"A:B"``); None when there is none."""
    names = sorted(ds.splits, key=lambda s: s.lower() != "test")
    for name in names:
        a, b = ds.ranges(name)["query"]
        if name != used and b - a >= MIN_FREE and all(min(b, d) <= max(a, c) for c, d in [*taken, *avoid]):
            return name
    gaps = _gaps([*taken, *avoid], len(ds.query))
    return f"{gaps[0][0]}:{gaps[0][1]}" if gaps and gaps[0][1] - gaps[0][0] >= MIN_FREE else None


def python_form(flag: str, value: str) -> str:
    """`` (EvalConfig(split='0:80') in Python)``: the option ``flag value`` as :func:`seqnet.evaluate` takes it."""
    return f" (EvalConfig({flag.lstrip('-').replace('-', '_')}={value!r}) in Python)"


def free_hint(ds: Dataset, trained: list[tuple[int, int]], chosen: list[tuple[int, int]], used: str,
              flag: str = "--split", avoid: Sequence[tuple[int, int]] = ()) -> str:
    """The hint of a warning on split ``used`` (given with ``flag``): ``flag S``, with S queries of ``ds`` free of
    the models' training (``trained``) and epoch-selection (``chosen``) query ranges and of ``avoid`` (the
    evaluated split, for a calibration split), never ``used`` itself; else S free of training queries only, said;
    else retraining apart from the split in use. Names the split in use when it is the test split (the numbers
    to keep clean: retrain)."""
    test = named_test_split(ds.splits)
    both = _free(ds, [*trained, *chosen], used, avoid)
    if both is not None and flag == "--split" and used == test:
        a, b = ds.ranges(test)["query"]
        return (f"retrain with --train-split / --val-split apart from the test split ({a}:{b}), or evaluate queries "
                f"free of the models' training and epoch-selection ones: --split {both}{python_form(flag, both)}")
    if both is not None:
        return f"{flag} {both}{python_form(flag, both)}" + (
            " (queries free of the models' training and epoch-selection ones)" if both not in ds.splits else "")
    some = _free(ds, trained, used, avoid)
    if some is not None:
        return (f"{flag} {some}{python_form(flag, some)} (free of the models' training queries, though an epoch "
                "was chosen on some)")
    return (f"no range of {MIN_FREE} or more queries is free of the models' training queries: retrain with "
            f"--train-split / --val-split that leave queries apart for {'calibration' if avoid else 'testing'}")
