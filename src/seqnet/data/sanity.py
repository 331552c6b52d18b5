"""Mistakes in a dataset that every command would accept and score: found when the dataset is built
(``seqnet dataset from-images``) and by ``seqnet dataset check``.

* :func:`check_frame_aligned`: frame-aligned ground truth (query frame i shows the place of reference frame
  i) with traverses of different lengths, or with image names that do not pair up (a missing image shifts
  the ground truth of every later frame): refused.
* :func:`dataset_warnings` (logged by :func:`review`): the query images are the reference images (every metric
  trivially perfect), splits that share queries (selection and test numbers optimistic), positions all within
  the radius of each other (constant GPS: every reference is correct, R@K trivially 1). One line each.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..core.errors import DatasetError
from ..core.log import logger
from ..core.memory import BLOCK_BYTES
from .traverse import Dataset

ALTERNATIVES = ("give the ground truth another way: --positives FILE (per query its matching reference indices) "
                "or positions (--ref-csv / --query-csv, --utm-names)")


def check_frame_aligned(ref_names: Sequence[str], query_names: Sequence[str], where: str = "--frame-aligned") -> None:
    """Raise :class:`DatasetError` unless query frame i can be the place of reference frame i: as many frames
    on both sides and, when the two traverses name their images alike (some names in common), the same name
    at every index."""
    n_r, n_q = len(ref_names), len(query_names)
    if n_r != n_q:
        raise DatasetError(f"{where}: query frame i is the place of reference frame i, but the reference has {n_r} "
                           f"images and the query {n_q}, so the ground truth cannot line up; hint: {ALTERNATIVES}")
    if not set(ref_names) & set(query_names):
        return  # named differently (two cameras, two clocks): nothing to pair by name
    for i, (r, q) in enumerate(zip(ref_names, query_names, strict=True)):
        if r != q:
            raise DatasetError(f"{where}: reference image {i} is {r!r} but query image {i} is {q!r}: an image "
                               "missing from one folder shifts every later frame and the ground truth would no "
                               f"longer line up; fix or remove them so both folders hold the same names, or "
                               f"{ALTERNATIVES}")


def review(ds: Dataset) -> list[str]:
    """Check ``ds`` as built: frame-aligned ground truth (recorded as ``"ground_truth": "frames"``) must pair up
    (:func:`check_frame_aligned`, else :class:`DatasetError`); every :func:`dataset_warnings` line is logged as a
    warning, and returned."""
    if ds.extra.get("ground_truth") == "frames":
        check_frame_aligned(ds.reference.names, ds.query.names, f"{ds.name}: frame-aligned ground truth")
    found = dataset_warnings(ds)
    for line in found:
        logger.warning("%s", line)
    return found


def dataset_warnings(ds: Dataset) -> list[str]:
    """One line per likely mistake in ``ds`` (none: an empty list): see the module's description."""
    found = [_copied_queries(ds), _shared_queries(ds), _constant_positions(ds)]
    return [f"{ds.name}: {line}" for line in found if line]


def _copied_queries(ds: Dataset) -> str | None:
    ref, qry = ds.reference.descriptors, ds.query.descriptors
    if ref.shape[1:] != qry.shape[1:] or ref.dtype != qry.dtype or len(qry) == 0:
        return None
    if ref.shape == qry.shape and _same_rows(ref, qry):
        return ("the query images are the reference images (identical descriptors, row for row): every metric is "
                "trivially perfect; hint: give the query traverse's own folder")
    copies = int(np.isin(_row_hashes(qry), _row_hashes(ref)).sum())
    if copies == len(qry):
        return (f"every one of the {len(qry)} query descriptors is an exact copy of a reference descriptor (the "
                "same images): every metric is trivially perfect; hint: give the query traverse's own images")
    return None


def _block_rows(a: np.ndarray) -> int:
    return max(1, BLOCK_BYTES // max(1, a.itemsize * int(np.prod(a.shape[1:])) * 8))


def _same_rows(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether ``a [N, D]`` and ``b [N, D]`` are equal, compared in blocks (bounded memory)."""
    step = _block_rows(a)
    return all(np.array_equal(a[i:i + step], b[i:i + step]) for i in range(0, len(a), step))


def _row_hashes(a: np.ndarray) -> np.ndarray:
    """``[N]`` uint64: a hash of every row's bytes (a fixed random linear form, wrapping), in blocks."""
    width = a.itemsize * int(np.prod(a.shape[1:]))
    weights = np.random.default_rng(0).integers(1, 2**63, size=width, dtype=np.uint64) | np.uint64(1)
    step, out = _block_rows(a), np.empty(len(a), np.uint64)
    for i in range(0, len(a), step):
        block = np.ascontiguousarray(a[i:i + step]).view(np.uint8).reshape(-1, width).astype(np.uint64)
        out[i:i + step] = (block * weights).sum(axis=1)  # modulo 2**64
    return out


def _shared_queries(ds: Dataset) -> str | None:
    """The pairs of splits whose query ranges overlap (as the calibration split and HVPR's val choice refuse)."""
    names = list(ds.splits)
    shared = []
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            (s, e), (t, f) = ds.splits[a]["query"], ds.splits[b]["query"]
            if max(s, t) < min(e, f):
                shared.append(f"{a} (queries {s}:{e}) and {b} (queries {t}:{f}) share {min(e, f) - max(s, t)}")
    if not shared:
        return None
    return (f"splits {'; '.join(shared)} queries: what is chosen or trained on one is then scored on the same "
            "queries, so the val / test numbers are optimistic (hint: give disjoint query ranges)")


def _constant_positions(ds: Dataset) -> str | None:
    """All positions within the radius of each other (the diagonal of their bounding box): every reference is
    a positive of every query (explicit positives decide instead, when there are some)."""
    if ds.positives is not None or not (len(ds.reference) and len(ds.query)):
        return None
    both = np.concatenate([ds.reference.positions, ds.query.positions])
    span = float(np.linalg.norm(both.max(axis=0) - both.min(axis=0)))
    if span > ds.radius:
        return None
    return (f"all {len(ds.reference)} reference and {len(ds.query)} query positions lie within {span:g} "
            f"{ds.position_unit} of each other, inside the radius {ds.radius:g}: every reference is within the "
            "radius of every query, so R@K is 1 trivially (hint: check the positions: constant GPS?)")
