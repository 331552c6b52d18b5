"""The public k-NN of arrays given by a user (``seqnet.knn``): rows checked for unit norm (or L2-normalised), then
:func:`seqnet.search.knn.knn`.

``evaluate()``, ``seqnet eval`` and the localiser L2-normalise every descriptor row before comparing;
:func:`seqnet.search.knn.knn` and :func:`seqnet.matching.seqmatch.seqmatch` rank the rows as given. On rows far
from unit norm the two rankings differ (R@1 0.17 against 0.37 on rescaled Nordland rows), so the public functions
say so (:func:`unit_rows_notice`, one WARNING line) unless told ``normalize=True`` (normalise, as the evaluation
does) or ``normalize=False`` (rank as given, no check). Every row is read once more, whatever ``normalize``
(:func:`row_checks`): a row holding NaN or inf is refused, naming it; an all-zero row (a failed descriptor: it
matches nothing, its neighbours are arbitrary ties) is said in one WARNING line naming it, as :class:`Traverse`
refuses it. Internal callers use the unchecked functions: they pay nothing for it.
"""

from __future__ import annotations

import numpy as np

from ..core.config import check_choice, check_int
from ..core.errors import ConfigError
from ..core.lazy import lazy_module
from ..core.log import counted, warn_once
from ..core.memmaps import read_rows
from ..core.tensors import NARROW_SPREAD, ArrayLike, as_tensor, direction_spread, l2_normalize, spread
from . import knn as exact

torch = lazy_module("torch")

UNIT_TOL = 1e-2  # |‖row‖ − 1| above this: far from unit norm (float16 rounding of unit rows stays well inside)
UNIT_SAMPLES = 4096  # rows checked, evenly spaced (a large memory map is not read whole for a warning)
NARROW_SAMPLES = 256  # rows whose direction spread is measured per call (real rows spread 30x the bound: enough)
CHECK_BYTES = 1 << 24  # rows read at a time by :func:`row_checks` (a memory map's pages are released after each)


def as_array(x: ArrayLike | list) -> ArrayLike:
    """``x`` as it is when a numpy array or a tensor, else (a list of rows) as a numpy array."""
    return x if isinstance(x, (np.ndarray, torch.Tensor)) else np.asarray(x)


def unit_rows_notice(x: ArrayLike, side: str, caller: str) -> str | None:
    """The warning line when a sample of the rows of ``x [N, D]`` is far from unit L2 norm (naming the first such
    row and its norm), else None; all-zero and non-finite rows are :func:`row_checks`' (skipped here)."""
    tensor = isinstance(x, torch.Tensor)
    if x.ndim != 2 or not x.shape[0] or (not tensor and x.dtype.kind not in "fiu"):
        return None  # the search refuses it, or nothing to check
    idx = spread(int(x.shape[0]), UNIT_SAMPLES)
    if tensor:
        rows = x[torch.as_tensor(idx, device=x.device)].detach().double().cpu().numpy()
    else:
        rows = np.asarray(x[idx], dtype=np.float64)
    norms = np.sqrt(np.einsum("ij,ij->i", rows, rows))
    bad = np.flatnonzero((np.abs(norms - 1.0) > UNIT_TOL) & (norms > 0) & np.isfinite(norms))
    if not bad.size:
        return None
    return (f"{caller}: {side} row {int(idx[bad[0]])} has L2 norm {norms[bad[0]]:.4g}, not 1 ({bad.size} of "
            f"{len(idx)} rows checked are not unit); {caller} compares the rows as given, while evaluate() and seqnet "
            f"eval L2-normalise every row first, so their rankings and R@K differ (hint: {caller}(..., normalize=True) "
            "ranks as evaluate() does; normalize=False ranks the rows as given without this check)")


def row_checks(x: ArrayLike, side: str, caller: str) -> str | None:
    """Every row of ``x [N, D]``, read in blocks of :data:`CHECK_BYTES`: a row holding NaN or inf is a
    :class:`ConfigError` naming it; the WARNING line for all-zero rows (naming the first), else None."""
    tensor = isinstance(x, torch.Tensor)
    if x.ndim != 2 or not x.shape[0] or (not tensor and x.dtype.kind not in "fiu"):
        return None  # the search refuses it, or nothing to check
    step, zeros, first = max(1, CHECK_BYTES // max(1, int(x.shape[1]) * 8)), 0, -1
    for s in range(0, int(x.shape[0]), step):
        finite, zero = _flags(x[s:s + step] if tensor else np.asarray(read_rows(x, s, s + step)))  # pages released
        if not finite.all():
            row = s + int(np.flatnonzero(~finite)[0])
            raise ConfigError(f"{caller}: {side} row {row} holds NaN or inf: it has no distance to any row (hint: "
                              "drop that row, e.g. a failed descriptor, or compute it again)")
        zero = np.flatnonzero(zero)
        first, zeros = (s + int(zero[0]) if first < 0 and zero.size else first), zeros + zero.size
    if not zeros:
        return None
    return (f"{caller}: {side} row {first} is all zeros ({counted(zeros, 'such row')} of {x.shape[0]}); a zero "
            "descriptor matches nothing: its scores say nothing and its ranking is arbitrary ties (hint: drop it, "
            "e.g. a blank image; Traverse and Dataset refuse such rows)")


def narrow_notice(pair: tuple[ArrayLike, ArrayLike], sides: tuple[str, str], caller: str) -> str | None:
    """The warning line when the rows of a side of ``pair`` point nearly the same way once L2-normalised
    (:func:`seqnet.core.tensors.direction_spread` below :data:`~seqnet.core.tensors.NARROW_SPREAD`: a common offset
    hundreds of times their spread), where float32 distances lose what tells them apart; else None."""
    for x, side in zip(pair, sides, strict=True):
        s = direction_spread(x, NARROW_SAMPLES) if isinstance(x, torch.Tensor) or x.dtype.kind in "fiu" else 1.0
        if s < NARROW_SPREAD:
            return (f"{caller}: the {side} rows point nearly the same way once L2-normalised (directions spread "
                    f"{s:.2g}; distinct places spread 0.3 or more): a common offset far larger than what tells them "
                    "apart, which float32 distances lose (R@1 0.99 -> 0.75 at an offset 1000 times the spread) "
                    "(hint: subtract a common mean from both sides, e.g. m = ref.mean(axis=0); "
                    f"{caller}(query - m, ref - m, ...))")
    return None


def _flags(block: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """``(finite [n], all zero [n])`` bool of the rows of ``block [n, D]`` (a tensor: on its device, any dtype)."""
    if isinstance(block, torch.Tensor):
        finite = torch.isfinite(block).all(dim=1) if block.is_floating_point() else torch.ones(len(block), dtype=bool)
        return finite.cpu().numpy(), (~(block != 0).any(dim=1)).cpu().numpy()
    finite = np.isfinite(block).all(axis=1) if block.dtype.kind == "f" else np.ones(len(block), bool)
    return finite, ~block.any(axis=1)


def prepared(query: ArrayLike | list, ref: ArrayLike | list, caller: str, normalize: bool | None,
             sides: tuple[str, str] = ("query", "reference")) -> tuple[ArrayLike, ArrayLike]:
    """``(query, ref)`` ready for the search: as arrays; L2-normalised rows (float tensors) when ``normalize``;
    checked for rows far from unit norm when ``normalize`` is None (one WARNING line, the first side found, said
    once per ``caller`` in a process: its advice, ``normalize=``, is the same for every batch of a loop and for
    every side); as given when False. Whatever ``normalize``, :func:`row_checks` first (a non-finite row refused,
    all-zero rows said once per ``caller``). ``sides``: the two arrays' names in the line."""
    if normalize is not None and not isinstance(normalize, (bool, np.bool_)):
        raise ConfigError(f"normalize must be True, False or None, got {normalize!r}")
    normalize = None if normalize is None else bool(normalize)
    pair = as_array(query), as_array(ref)
    for x, side in zip(pair, sides, strict=True):
        line = row_checks(x, side, caller)
        if line:
            warn_once(("zero rows", caller), "%s", line)
    line = narrow_notice(pair, sides, caller) if normalize is not False else None
    if line:
        warn_once(("narrow rows", caller), "%s", line)
    if normalize:
        return tuple(l2_normalize(as_tensor(x, name=side, ndim=2, keep_float64=True))
                     for x, side in zip(pair, sides, strict=True))
    if normalize is None:
        for x, side in zip(pair, sides, strict=True):
            line = unit_rows_notice(x, side, caller)
            if line:
                warn_once(("unit rows", caller), "%s", line)
                break
    return pair


def knn(query: ArrayLike, ref: ArrayLike, k: int, backend: str = "torch", metric: str = "l2",
        device: str | None = None, block_bytes: int | None = None,
        normalize: bool | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Exact k nearest references of each query (:func:`seqnet.search.knn.knn`), on the rows as given.

    Args:
        query: ``[Nq, D]``; ref: ``[Nr, D]`` (numpy, torch, or lists of rows).
        k: neighbours per query (capped at Nr).
        backend: ``"torch"`` (blocked GEMM, GPU when present) or ``"faiss"`` (flat index).
        metric: ``"l2"`` (ascending Euclidean distance) or ``"ip"`` (descending inner product).
        device: torch device (torch backend).
        block_bytes: memory budget of one block of distances (torch backend; default 64 MiB).
        normalize: ``True``: L2-normalise every row first, as ``evaluate()`` and ``seqnet eval`` do (the same
            ranking as theirs); ``None`` (default): rank the rows as given, with a WARNING line when rows are far
            from unit norm (then the ranking differs from the evaluation's); ``False``: as given, without the
            unit-norm check. Any ``normalize``: a row with NaN / inf is refused, all-zero rows are said (one line).

    Returns:
        ``(scores [Nq, k], indices [Nq, k])`` as numpy, best first (scores first: unpack as ``scores, idx``).
    """
    if metric == "cosine":  # checked before the rows: the arguments' errors come before the rows' warnings
        raise ConfigError("metric 'cosine' is not one of l2, ip (hint: cosine similarity is metric='ip' with "
                          "normalize=True)")
    check_choice("metric", metric, exact.METRICS)
    check_choice("k-NN backend", backend, exact.KNN_BACKENDS)
    check_int("k", k, 1)
    q, r = prepared(query, ref, "knn", normalize)
    return exact.knn(q, r, k, backend, metric, device, block_bytes)
