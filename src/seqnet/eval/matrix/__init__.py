"""Evaluation on a precomputed ``[Nq, Nr]`` distance or similarity matrix (``seqnet eval --distances FILE``).

VPR-Bench, VPR_Tutorial and many tools hand over a matrix instead of descriptors. The matrix covers
the dataset's whole query and reference traverses (row i: query frame i, column j: reference frame
j); a split evaluates its sub-matrix. A similarity matrix (``--similarity``, higher is closer) is
negated: SeqMatch then sums similarities, and the lowest score wins as for distances. The methods
and the one evaluation loop are those of :func:`seqnet.eval.runner.run`, on a
:class:`seqnet.reference.matrix.MatrixReference`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ...core.errors import ConfigError, DatasetError
from ...core.memmaps import read_rows
from ...core.memory import BLOCK_BYTES as MEMORY_BLOCK
from ...core.stage import Written
from ...data.resample import kept_indices, resample_dataset
from ...data.traverse import Dataset, default_split
from ...methods.grammar import Method, parse_method
from ...reference.matrix import MatrixQuery, MatrixReference, matrix_methods
from ...search.given import GivenMatrix
from ...security.arrays import read_npy
from ...security.digests import file_digest
from ...sequence.windows import Windows
from ..config import EvalConfig
from ..evaluation import Evaluation, merge, method_windows
from ..notices import add_warnings, radius_ignored, shift_notice, split_note, trivial_ks
from ..outputs import EvalOutputs
from ..runner import run
from ..score import dataset_truth, item_names
from .orientation import orientation_check

DEFAULT_MATRIX_METHODS = ("single", "raw+seqmatch", "hvpr-single:raw+seqmatch")


class ReadMatrix(np.ndarray):
    """The distances ``[Nq, Nr]`` float64 that :func:`read_matrix` made, with the reading it applied:
    ``reading`` = ``(similarity, transposed)``. :func:`evaluate_matrix` reads it as distances, one row per query,
    and names that reading in its hints; a ``similarity`` or ``transposed`` that contradicts it is refused, so the
    reading is never applied twice. A view (slice) keeps it; ``np.asarray(m)`` is a plain array again."""

    reading: tuple[bool, bool] | None = None

    def __array_finalize__(self, obj: Any) -> None:
        self.reading = getattr(obj, "reading", None)


def read_matrix(path: str | Path, ds: Dataset, similarity: bool | None = None, split: str | None = "all",
                transposed: bool = False) -> ReadMatrix:
    """The ``[Nq, Nr]`` matrix of ``path`` (``.npy``, one row per query and one column per reference frame of
    the whole dataset ``ds``; ``transposed``: one row per reference, ``[Nr, Nq]``, as VPR_Tutorial's ``S``),
    restricted to the rows and columns of ``split`` (a name, a range spec, or ``all``: :meth:`Dataset.ranges`)
    and as distances (float64, in memory: :func:`open_matrix` reads it block by block instead): a
    :class:`ReadMatrix`, which carries the reading applied (``similarity``, ``transposed``) so that
    :func:`evaluate_matrix` does not apply it again."""
    given = open_matrix(path, ds, similarity, split, transposed)
    if given.unchecked:
        check_finite_rows(given.raw, path)
    out = given.dense().view(ReadMatrix)
    out.reading = (bool(similarity), bool(transposed))
    return out


def open_matrix(path: str | Path, ds: Dataset, similarity: bool | None = None, split: str | None = "all",
                transposed: bool = False) -> GivenMatrix:
    """The matrix of ``path`` as :func:`read_matrix` describes it, as a :class:`seqnet.search.given.GivenMatrix`
    over the (memory-mapped) file in its own dtype: nothing is converted or copied. When the split is a part
    of the matrix, every entry of the file is checked finite here; else the first pass over it checks
    (``unchecked`` is set)."""
    m = _vpr_bench_scores(path, similarity) if _holds_objects(path) else read_npy(path, True, "--distances",
                                                                                   ConfigError)
    want = (len(ds.reference), len(ds.query)) if transposed else (len(ds.query), len(ds.reference))
    if m.ndim != 2 or m.shape != want:
        rows, cols = ("reference", "query") if transposed else ("query", "reference")
        turned = m.ndim == 2 and m.shape == want[::-1]
        hint = f"; it is the other way round: {'drop' if transposed else 'pass'} --transposed" if turned else ""
        raise ConfigError(f"distance matrix {path}: shape {m.shape}, but dataset {ds.name!r} has {len(ds.query)} query "
                          f"and {len(ds.reference)} reference frames (one row per {rows} frame, one column per "
                          f"{cols} frame{', as --transposed says' if transposed else ''}){hint}")
    rng = ds.ranges(split)
    given = GivenMatrix(m, bool(similarity), bool(transposed), f"distance matrix {path}")
    given = given.block(slice(*rng["query"]), slice(*rng["reference"]))  # a view: only the split's block is read
    whole = given.raw.shape == m.shape
    if not whole:
        check_finite_rows(m, path)
    given.unchecked = whole
    return given


def _holds_objects(path: str | Path) -> bool:
    """Whether the ``.npy`` file ``path`` declares Python objects (a pickle) rather than numbers."""
    from ...security.arrays import read_header
    from ...security.inputs import open_input

    with open_input(path, "--distances", ConfigError) as f:
        try:
            return read_header(f, str(path), ConfigError)[2] == np.dtype(object)
        except ConfigError:
            return False  # read_npy says what is wrong


def _vpr_bench_scores(path: str | Path, similarity: bool | None) -> np.ndarray:
    """The score matrix ``[Nq, Nr]`` (element 3, higher is better) of VPR-Bench's ``precomputed_data_corrected.npy``
    (an object array: query indices, best references, best scores, scores, encode and match times), read with
    seqnet's data-only unpickler; any other pickled ``.npy`` is refused. ``similarity`` must be said: True (as
    VPR-Bench writes it), or False for a file whose matrix holds distances (``--no-similarity``: the sense check's
    hint could not be followed before, dropping --similarity was refused)."""
    from ...security.unpickle import load_npy_objects

    x = load_npy_objects(path, "--distances", ConfigError)
    m = x[3] if isinstance(x, np.ndarray) and x.shape == (6,) and isinstance(x[3], np.ndarray) else None
    if m is None or m.ndim != 2 or m.dtype.kind not in "fiu":
        raise ConfigError(f"distance matrix {path}: holds Python objects, not a matrix of numbers (VPR-Bench's "
                          "precomputed_data_corrected.npy is read; this is not one)")
    if similarity is None:
        raise ConfigError(f"distance matrix {path}: a VPR-Bench precomputed file holds similarities (higher is "
                          "better): add --similarity (similarity=True in Python); if its matrix holds distances, "
                          "--no-similarity (similarity=False)")
    return m


def check_finite_rows(m: np.ndarray, path: str | Path, block_bytes: int = MEMORY_BLOCK) -> None:
    """Every entry of the (memory-mapped) matrix ``m`` is finite, checked in blocks of rows (bounded memory)."""
    step = max(1, block_bytes // max(1, m.shape[1] * m.itemsize))
    for a in range(0, m.shape[0], step):
        bad = ~np.isfinite(read_rows(m, a, a + step))  # a large map's pages released after each block
        if bad.any():
            r, c = np.argwhere(bad)[0]
            v = m[r + a, c]
            hint = ("hint: give masked pairs a finite value past every real one, e.g. m[~np.isfinite(m)] = "
                    "np.nanmax(np.where(np.isfinite(m), m, np.nan)) + 1 for distances (the smallest minus 1 for "
                    "similarities)" if np.isinf(v) else "hint: compute those entries again, or drop their rows")
            raise DatasetError(f"distance matrix {path}: entry [{r + a}, {c}] is {v} (every entry must be finite; "
                               f"{hint})")


def evaluate_matrix(ds: Dataset, dist: np.ndarray | GivenMatrix, conf: EvalConfig | None = None,
                    similarity: bool | None = None, transposed: bool | None = None) -> Evaluation:
    """Evaluate ``conf.methods`` (default :data:`DEFAULT_MATRIX_METHODS`) of ``ds`` (the split already taken)
    on the matrix ``dist`` between its query and reference frames: a plain array ``[Nq, Nr]`` of distances,
    of similarities (higher is closer) when ``similarity``, ``[Nr, Nq]`` (one row per reference, as
    VPR_Tutorial's ``S``) when ``transposed`` (the only input the two flags apply to); or a matrix that carries
    its own reading: a :class:`GivenMatrix` (:func:`open_matrix`) or a :class:`ReadMatrix` (:func:`read_matrix`,
    already distances, one row per query), where a flag that contradicts that reading is refused. The
    orientation check names a reading that fits the ground truth better."""
    for name, flag in (("similarity", similarity), ("transposed", transposed)):
        if flag is not None and not isinstance(flag, (bool, np.bool_)):
            raise ConfigError(f"{name}={flag!r}: give True, False or None (a string such as 'no' would read as True)")
    radius = conf.radius if conf is not None else None  # as given: moot with explicit positives
    conf = (conf or EvalConfig(methods=DEFAULT_MATRIX_METHODS)).resolve({}, ds.radius)
    given = as_given(dist, similarity, transposed)
    ds, given, query_range = split_matrix(ds, given, conf.split)
    if given.shape != (len(ds.query), len(ds.reference)):
        rows, cols = ("reference", "query") if given.transposed else ("query", "reference")
        raise ConfigError(f"the distance matrix is {list(given.raw.shape)} for {len(ds.query)} query and "
                          f"{len(ds.reference)} reference frames (one row per {rows}, one column per {cols})")
    similarity, transposed = getattr(dist, "reading", None) or (given.negate, given.transposed)  # for the hints
    keep = None
    if conf.resample_every is not None:  # the kept frames' rows and columns
        keep = kept_indices(ds, conf.resample_every, conf.resample_side)
        given = GivenMatrix(given[np.ix_(keep["query"], keep["reference"])])
        ds = resample_dataset(ds, conf.resample_every, conf.resample_side)
    methods = [parse_method(n) for n in conf.methods]
    out = merge([_matrix_group(ds, given, ms, w, conf) for w, ms in
                 method_windows(methods, conf.windows, conf.common_queries).items()], conf.methods)
    out.results["config"] = {**conf.to_dict(), "dataset": ds.name, "device": "cpu", "models": {},
                             "ground_truth": "explicit positives" if ds.positives is not None else "radius",
                             "matrix_methods": list(matrix_methods())}
    out.frame_names = (ds.query.names, ds.reference.names)
    out.frame_numbers = (keep["query"], keep["reference"]) if keep else (None, None)
    if query_range is not None:  # per-query numbering (VME, --per-query): rows of the dataset's whole lists
        out.results["config"].update(query_range=list(query_range["query"]),
                                     reference_range=list(query_range["reference"]))
    out.dataset, out.matrix = ds, given  # for the report: the evaluated frames and their given distances
    check = orientation_check(ds, given, similarity, transposed)  # its warning is said there: kept here
    out.results["matrix_check"] = {k: v for k, v in check.items() if k != "warning"}
    if "warning" in check:
        out.results["warnings"] = [*out.results.get("warnings", []), check["warning"]]
    shift = None if "warning" in check else shift_notice(out)  # a matrix read the wrong way looks shifted too
    add_warnings(out, [constant_rows(given), shift, radius_ignored(radius, ds.positives is not None),
                       trivial_ks(out, conf.ks)])
    return out


def split_matrix(ds: Dataset, given: GivenMatrix, split: str | None
                 ) -> tuple[Dataset, GivenMatrix, dict[str, tuple[int, int]] | None]:
    """``(ds, given, ranges)`` of the split ``split``: a dataset that defines it (a name or a range spec)
    with the whole matrix ``[Nq, Nr]`` gives its split and the split's block of the matrix (a view; the query
    and reference ranges recorded), or with the split's block already taken, its split; None / ``all``, or a
    dataset already split (no splits of its own) with a matrix of its size, is evaluated as given. Anything else is
    refused: never a whole matrix scored under a split's name."""
    whole = (len(ds.query), len(ds.reference))
    if split in (None, "all"):
        return ds, given, None
    rng = ds.ranges(split)
    if rng is None:
        if not ds.splits and given.shape == whole:
            return ds, given, None  # ds.split(name) with its matrix: that split, already taken
        raise ConfigError(f"split {split!r}: dataset {ds.name!r} defines "
                          f"{'the splits ' + ', '.join(ds.splits) if ds.splits else 'no splits'}; hint: "
                          "EvalConfig(split=None) evaluates the dataset and matrix as given")
    sub = ds.split(split)
    if given.shape != whole:
        return sub, given, None  # the split's block, already taken (checked against the split's size next)
    return sub, given.block(slice(*rng["query"]), slice(*rng["reference"])), rng


def as_given(dist: np.ndarray | GivenMatrix, similarity: bool | None, transposed: bool | None) -> GivenMatrix:
    """``dist`` as a :class:`GivenMatrix`: a plain array read as ``similarity`` and ``transposed`` say (None:
    False); a given matrix as it was opened, and a :class:`ReadMatrix` as the distances it holds (a
    ``similarity`` or ``transposed`` that contradicts the reading either carries is refused: never applied
    twice)."""
    reading = (dist.negate, dist.transposed) if isinstance(dist, GivenMatrix) else getattr(dist, "reading", None)
    if reading is not None:
        opened = isinstance(dist, GivenMatrix)
        for name, said, held in (("similarity", similarity, reading[0]), ("transposed", transposed, reading[1])):
            if said is not None and bool(said) != held:
                how = (f"the matrix was opened with {name}={held} (open_matrix reads it so)" if opened else
                       f"read_matrix already applied {name}={held} (it returns distances, one row per query)")
                raise ConfigError(f"{name}={said!r}, but {how}: leave {name} out, or read the file again with "
                                  f"{name}={said!r}")
    if isinstance(dist, GivenMatrix):
        return dist
    m = np.asarray(dist)  # a ReadMatrix: distances, one row per query, its reading already applied
    if m.ndim != 2:
        raise ConfigError(f"the distance matrix has shape {list(m.shape)}: it must be 2-D, one row per query")
    return GivenMatrix(m) if reading is not None else GivenMatrix(m, bool(similarity), bool(transposed))


def constant_rows(given: GivenMatrix) -> str | None:
    """Why the matrix cannot rank: every row (or at least half of them) holds one value, so its best and worst
    reference are the same (:meth:`seqnet.search.given.GivenMatrix.best`, the first on ties); None otherwise."""
    best = given.best()
    same = best["as given"] == best["other sense"]
    n, nq = int(same.sum()), len(same)
    if nq == 0 or n < nq / 2:
        return None
    if n < nq:
        return f"{n} of the {nq} rows of the matrix are constant: for those queries every rank is a tie broken by index"
    if np.ptp(given[:, np.array([0])]) == 0:
        return "the matrix is constant: it carries no information, every rank is a tie broken by index"
    return ("every row of the matrix is constant: it carries no information on which reference matches, every rank "
            "is a tie broken by index")


def _matrix_group(ds: Dataset, d: GivenMatrix, methods: list[Method], windows: Windows, conf: EvalConfig
                  ) -> Evaluation:
    """The methods that share ``windows``, on those windows' items of the matrix ``d [Nq, Nr]``."""
    query = MatrixQuery(len(ds.query), ds.query.seq_bounds, windows)
    ref = MatrixReference(d, ds.reference, windows, ds.name)
    truth = dataset_truth(ds, query.side.items, ref.items, conf.radius)
    out = run(methods, query, ref, truth, conf, len(ds.query),
              lambda m: {**m.summary(), "on": "distance matrix", "seq_len": conf.windows.seq_len,
                         "match_len": conf.windows.match_len, "top_k": conf.shortlist_size(m)}, windows=windows,
              with_torch=any(m.kind != "knn" for m in methods))  # single on a matrix runs in NumPy
    out.query_names, out.reference_names = item_names(ds.query, query.side.items), item_names(ds.reference, ref.items)
    return out


def main(conf: EvalConfig, dataset: str | Path, distances: str | Path, out: str | Path | None,
         similarity: bool | None = None, per_query: str | Path | None = None, report: Any = None, figures: bool = False,
         overwrite: bool = False, json: str | Path | None = None, transposed: bool = False) -> Written:
    """Stage: evaluate ``conf.split`` of the dataset directory ``dataset`` on the matrix file ``distances``
    (``similarity``: higher is closer; ``transposed``: one row per reference); writes ``out/results.json``
    (results, config, inputs) and what
    ``per_query``, ``report``, ``figures`` and ``json`` ask, as :func:`seqnet.eval.evaluate.main` does."""
    from ...data.io import load_dataset

    defaults = conf.methods == EvalConfig().methods
    conf = conf.merge(methods=DEFAULT_MATRIX_METHODS if defaults else conf.methods)
    outputs = EvalOutputs(out, per_query, json, figures, report, overwrite)
    with outputs.session(conf.methods):
        ds = load_dataset(dataset)
        split = default_split(conf.split, ds.splits)
        sub = ds.split(split)  # a bad split is refused here, before the matrix is read
        dist = open_matrix(distances, ds, similarity, split, transposed)
        ev = evaluate_matrix(sub, dist, conf.merge(split="all"))  # the split taken; the reading open_matrix's
        ev.results["config"]["split"] = split
        rng = ds.ranges(split)  # per-query numbering: rows of the dataset's whole lists
        ev.results["config"].update(query_range=list(rng["query"]), reference_range=list(rng["reference"]))
        add_warnings(ev, [split_note(conf.split, list(ds.splits), len(sub.query))])
        ev.results["inputs"] = {"dataset": str(Path(dataset).resolve()), "distances": str(Path(distances).resolve()),
                                "similarity": bool(similarity), "transposed": bool(transposed),
                                "distances_digest": file_digest(distances)}
        return outputs.write(ev)
