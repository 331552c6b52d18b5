"""Which reading of a given matrix was meant: as given, the other sense (similarity vs distance), or, for a
square matrix whose shape cannot tell rows from columns, transposed (``seqnet eval --distances``'s check).

With the ground truth, each reading's single-frame R@1 is measured on a sample of the queries; the sense
is chosen first (a clearly better sense), then the transposed layout of that sense only when it beats
the untransposed one beyond chance (a sign test): two aligned traverses read about as well either way.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...core.log import logger
from ...core.memory import BLOCK_BYTES as MEMORY_BLOCK
from ...data.traverse import Dataset
from ...search.given import GivenMatrix
from ...security.text import shown
from ..score import dataset_truth

CHECK_ROWS = 2000  # queries sampled to compare the matrix's readings (a cheap argmin each)


def orientation_check(ds: Dataset, dist: np.ndarray | GivenMatrix, similarity: bool, transposed: bool = False
                      ) -> dict[str, Any]:
    """Single-frame R@1 of the matrix read as given and read the other ways a user may have meant (the other
    sense: similarity vs distance; transposed, for a square matrix), on up to :data:`CHECK_ROWS` queries with
    a true match; a warning names the reading :func:`choose_reading` picks when it is not the one used
    (:func:`_warn_reading`; ``transposed``: the file was read transposed, as --transposed says)."""
    q = np.arange(len(ds.query))
    truth = dataset_truth(ds, q, np.arange(len(ds.reference)), ds.radius)
    keep = np.flatnonzero(truth.has_positive())
    keep = keep[np.linspace(0, len(keep) - 1, min(len(keep), CHECK_ROWS)).round().astype(np.int64)] if len(keep) \
        else keep
    sampled = dataset_truth(ds, keep, np.arange(len(ds.reference)), ds.radius) if len(keep) else None
    hits = {k: sampled.hits(top[:, None])[:, 0] if sampled else np.zeros(0, bool)
            for k, top in _top1(dist, keep).items()}
    r1 = {k: float(h.mean()) if len(h) else float("nan") for k, h in hits.items()}
    best = choose_reading(hits)
    said = None if best == "as given" else _warn_reading(best, r1, similarity, transposed,
                                                         sign_z(hits[best], hits["as given"]))
    return {"single_r@1": {k: round(v, 4) for k, v in r1.items()}, "queries_checked": int(len(keep)),
            "best_reading": best, **({"warning": said} if said else {})}


def much_better(r1: float, than: float) -> bool:
    """Whether a reading's R@1 ``r1`` is clearly better than ``than``: at least twice, and 0.1 above."""
    return bool(r1 >= 2 * than and r1 >= than + 0.1)


def choose_reading(hits: dict[str, np.ndarray]) -> str:
    """The reading of the matrix that the per-query hits ``[M]`` bool of each reading (:func:`_top1`'s keys) say
    was meant: the sense first (the other sense when its better layout is :func:`much_better` than the given
    sense's better layout), then, for a square matrix, the transposed layout of that sense only when it beats
    the untransposed one beyond chance (the sign test's z at least :data:`SQUARE_Z`): two aligned traverses
    read about as well either way, and a few queries' noise must not name a flag."""
    r1 = {k: float(h.mean()) if len(h) else 0.0 for k, h in hits.items()}
    senses = {"as given": ("as given", "transposed"), "other sense": ("other sense", "transposed, other sense")}
    top = {s: max(r1.get(k, -1.0) for k in keys) for s, keys in senses.items()}
    plain, turned = senses["other sense" if much_better(top["other sense"], top["as given"]) else "as given"]
    if turned in hits and clearly_transposed(hits[turned], hits[plain]):
        return turned
    return plain


SQUARE_Z = 2.5  # a square matrix reading better transposed on this many standard errors is named (sign test)
SMALL_Z = 2.0  # ... or much better (twice, and 0.1 above) on at least this many: a small sample's clear case


def clearly_transposed(turned: np.ndarray, plain: np.ndarray) -> bool:
    """Whether the transposed layout's per-query hits ``turned [M]`` beat the untransposed ``plain [M]`` beyond
    chance: the sign test's z at least :data:`SQUARE_Z`, or :func:`much_better` with z at least :data:`SMALL_Z`
    (a few dozen queries of a truly transposed matrix: e.g. R@1 0.50 against 0.17 on 12 queries, z 2.0)."""
    z = sign_z(turned, plain)
    return z >= SQUARE_Z or (much_better(float(turned.mean()), float(plain.mean())) and z >= SMALL_Z)


def _top1(dist: np.ndarray | GivenMatrix, keep: np.ndarray, block_bytes: int = MEMORY_BLOCK
          ) -> dict[str, np.ndarray]:
    """Each reading's best reference ``[len(keep)]`` for the queries ``keep`` of ``dist [Nq, Nr]``: as given
    (argmin of the row), the other sense (argmax), and for a square matrix transposed (of the column) and
    transposed in the other sense; in blocks of rows or columns of at most ``block_bytes`` (a given matrix:
    from its one pass, :meth:`seqnet.search.given.GivenMatrix.scan`)."""
    if isinstance(dist, GivenMatrix):
        return {k: v[keep] for k, v in dist.best().items()}
    out: dict[str, list[np.ndarray]] = {"as given": [], "other sense": []}
    step = max(1, block_bytes // max(1, dist.shape[1] * 8))
    for a in range(0, len(keep), step):
        rows = np.asarray(dist[keep[a:a + step]], dtype=np.float64)
        out["as given"].append(rows.argmin(1))
        out["other sense"].append(rows.argmax(1))
    if dist.shape[0] == dist.shape[1]:
        out |= {"transposed": [], "transposed, other sense": []}
        step = max(1, block_bytes // max(1, dist.shape[0] * 8))
        for a in range(0, len(keep), step):
            cols = np.asarray(dist[:, keep[a:a + step]], dtype=np.float64)
            out["transposed"].append(cols.argmin(0))
            out["transposed, other sense"].append(cols.argmax(0))
    return {k: np.concatenate(v) if v else np.zeros(0, np.int64) for k, v in out.items()}


def sign_z(better: np.ndarray, given: np.ndarray) -> float:
    """The sign test's z of two readings' per-query hits ``[M]`` bool: ``(b - c) / sqrt(b + c)`` over the queries
    where exactly one is right (b: ``better`` only, c: ``given`` only); 0 when none differ."""
    b, c = int((better & ~given).sum()), int((given & ~better).sum())
    return (b - c) / np.sqrt(b + c) if b + c else 0.0


def _warn_reading(best: str, r1: dict[str, float], similarity: bool, transposed: bool, z: float = 0.0) -> str:
    """A warning naming the reading :func:`choose_reading` chose, ``best`` (not "as given": the decision has passed
    its thresholds, so it is always said): how clearly it beats the one used (:func:`much_better`), or, for a
    square matrix whose shape cannot tell rows from columns, the sign test's ``z``; else every reading's R@1.
    ``similarity``, ``transposed``: how the matrix was read (a ``transposed`` reading of a matrix read with
    --transposed has one row per query). Logged, and returned (kept in the results' warnings)."""
    given, sense = r1["as given"], "similarities" if similarity else "distances"
    other = "distances" if similarity else "similarities"
    rows, turned_rows = ("reference", "query") if transposed else ("query", "reference")
    flag = ("drop --similarity (similarity=False in Python; --no-similarity for a VPR-Bench file)" if similarity else
            "pass --similarity (similarity=True in Python)")
    turn = ("drop --transposed (transposed=False)" if transposed else
            "pass --transposed (transposed=True in Python; one row per reference, as VPR_Tutorial's S)")
    hint = {"other sense": flag, "transposed": turn, "transposed, other sense": f"{turn}, and {flag}"}[best]
    layout = f"{sense}, read transposed: one row per reference" if transposed else f"{sense}, one row per query"
    if much_better(r1[best], given):
        read = {"other sense": f"as {other}", "transposed": f"with one row per {turned_rows}, as {sense}",
                "transposed, other sense": f"with one row per {turned_rows}, as {other}"}[best]
        msg = (f"the matrix reads much better {read} (the {best} reading): single-frame R@1 is {given:.3f} read "
               f"as given ({layout}) but {r1[best]:.3f} read {read}, so it was most likely written that way "
               f"(hint: {hint})")
    elif best.startswith("transposed") and z >= SQUARE_Z:
        msg = (f"a square matrix: read with one row per {rows} (single-frame R@1 {given:.3f}), but it reads "
               f"better {best} ({r1[best]:.3f}, one row per {turned_rows}; sign test z = {z:.1f} over the queries "
               f"where the two readings disagree); if its rows and columns are the other way round, {hint}")
    else:  # chosen on the sense's best layout (or a small sample): every reading other than the one given is said
        told = ", ".join(f"{k} {v:.3f}" for k, v in r1.items())
        read = best.replace("other sense", f"as {other}")
        msg = (f"the matrix reads better {read} than as given ({layout}): single-frame R@1 by reading: {told}, so "
               f"it was most likely written that way (hint: {hint})")
    logger.warning("%s", shown(msg))
    return msg
