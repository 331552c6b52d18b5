"""A reference that passes the same places twice while its ground truth knows only one pass
(:func:`revisited_reference`): top-1s on the other pass count as wrong, and training mines them as negatives."""

from __future__ import annotations

import numpy as np

from ...core.tensors import spread
from ..traverse import Dataset

REVISIT_SAMPLES = 200  # reference rows looked at (evenly spaced)
REVISIT_BYTES = 128 << 20  # reference rows compared with them, and their distances, at most (evenly spaced beyond)
REVISIT_RATIO = 0.25  # nearest other stretch's image nearer than this share of the median other image: the same place
REVISIT_LEFT = 0.5  # ... while the frame midway between them is farther than this share: the route left and came back
REVISIT_RUN = 4  # consecutive sampled rows whose partners run alongside, at least
REVISIT_MIN, REVISIT_SHARE = 5, 0.02  # sampled rows revisited, at least, and at least this share of the sample
LAGS = 2 ** np.arange(12)  # frame lags that measure how long one place stays in view


def revisited_reference(ds: Dataset) -> str | None:
    """Why the reference looks like it passes the same places twice unknown to the ground truth: of
    :data:`REVISIT_SAMPLES` reference rows, at least :data:`REVISIT_MIN` (and :data:`REVISIT_SHARE`) have an image
    elsewhere on the reference (beyond the stretch that one place stays in view: :func:`_in_view`) nearer than
    :data:`REVISIT_RATIO` of their median distance to the reference, with a different image midway (not a stop, not
    one long view), partners that run alongside theirs (:func:`_in_step`), and no query in common in the ground truth
    (explicit positives), or positions more than two radii apart; None otherwise."""
    desc = ds.reference.descriptors
    n = len(desc)
    if n < 20 or desc.ndim != 2:
        return None
    i = spread(n, REVISIT_SAMPLES)
    # candidates: their rows, and the [S, C] distances with their temporaries (about 4 copies), within the bound
    c = spread(n, max(REVISIT_SAMPLES, REVISIT_BYTES // (8 * max(desc.shape[1], 4 * REVISIT_SAMPLES))))
    rows, cand = unit_rows(desc[i]), unit_rows(desc[c])
    d = np.sqrt(np.maximum(2.0 - 2.0 * (rows @ cand.T), 0.0))  # [S, C]
    typical = np.median(d, axis=1)
    view = 2 * _in_view(desc, i, typical)  # frames one place stays in view, both ways
    away = np.abs(c[None, :] - i[:, None]) > view
    d = np.where(away, d, np.inf)
    k = d.argmin(axis=1)
    j, near = c[k], d[np.arange(len(i)), k]
    mid = np.linalg.norm(rows - unit_rows(desc[(i + j) // 2]), axis=1)
    found = (near < REVISIT_RATIO * typical) & (mid > REVISIT_LEFT * typical) & ~_same_place(ds, i, j)
    found &= _in_step(i, j, found, view)
    if found.sum() < max(REVISIT_MIN, REVISIT_SHARE * len(i)):
        return None
    a, b = np.maximum(i, j)[found], np.minimum(i, j)[found]
    (a0, a1), (b0, b1), groups = _stretch(a, b, max(1, n // len(i)))
    more = f"; {groups} such stretches" if groups > 1 else ""
    return (f"reference frames {a0}:{a1} closely resemble frames {b0}:{b1} ({found.sum()} of {len(i)} sampled frames "
            f"have a near copy far away in the reference{more}) but the ground truth gives them no query in common: "
            "the reference passes the same places twice? (top-1s on the other pass count as wrong; hint: give the "
            "reference's positions (GPS), or list both passes in the positives)")


def unit_rows(a: np.ndarray) -> np.ndarray:
    """``a [K, D]`` as float64 rows of unit length (zero rows kept)."""
    a = np.asarray(a, np.float64)
    return a / np.maximum(np.linalg.norm(a, axis=1, keepdims=True), 1e-12)


def nearer_share(x: np.ndarray, own: np.ndarray, other: np.ndarray, far: np.ndarray, min_others: int,
                 min_rows: int) -> float | None:
    """The median, over the rows of ``x [S, D]`` with at least ``min_others`` rows of ``other [S', D]`` marked in
    ``far [S, S']`` (another place), of the share of those that are nearer to the row (L2-normalised) than its own
    row of ``own [S, D]``: near 0 when each row's own is its place, near 0.5 when it is any; None with fewer than
    ``min_rows`` such rows."""
    count = far.sum(axis=1)
    ok = count >= min_others
    if ok.sum() < min_rows:
        return None
    x, own, other = unit_rows(x), unit_rows(own), unit_rows(other)
    d_own = np.linalg.norm(x - own, axis=1)  # [S]
    d = np.sqrt(np.maximum(2.0 - 2.0 * (x @ other.T), 0.0))  # [S, S']: unit rows (zero rows: as far as any)
    return float(np.median(((d < d_own[:, None]) & far).sum(axis=1)[ok] / count[ok]))


def _in_view(desc: np.ndarray, i: np.ndarray, typical: np.ndarray) -> int:
    """Frames one place stays in view: the smallest of :data:`LAGS` at which the median row of ``i [S]`` is farther
    from the frame that lag later than :data:`REVISIT_LEFT` of its ``typical [S]`` distance (high frame rates: many
    frames; the last lag when none is)."""
    n = len(desc)
    for lag in LAGS:
        at = i[i + lag < n]
        if len(at) < 3:
            break
        step = np.linalg.norm(unit_rows(desc[at]) - unit_rows(desc[at + lag]), axis=1)
        if np.median(step / typical[i + lag < n]) > REVISIT_LEFT:
            return int(lag)
    return int(LAGS[-1])


def _in_step(i: np.ndarray, j: np.ndarray, found: np.ndarray, slack: int) -> np.ndarray:
    """``[S]`` bool: whether sampled row ``i[k]`` lies in a run of at least :data:`REVISIT_RUN` consecutive sampled
    rows, all ``found``, whose partners ``j`` lie as far along as each other (``i - j`` within ``slack`` plus twice
    the rows between them): a second pass runs alongside the first, while chance look-alikes (few dimensions,
    repetitive scenery) scatter."""
    link = found[1:] & found[:-1] & (np.abs(np.diff(i - j)) <= slack + 2 * np.diff(i))  # [S - 1]
    edges = np.flatnonzero(np.diff(np.r_[0, link.astype(np.int8), 0]))
    out = np.zeros(len(i), bool)
    for a, b in zip(edges[::2], edges[1::2], strict=True):  # links a..b-1 join rows a..b
        if b - a + 1 >= REVISIT_RUN:
            out[a:b + 1] = True
    return out


def _same_place(ds: Dataset, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """``[S]`` bool: whether the ground truth lets reference rows ``i [S]`` and ``j [S]`` be one place: a query in
    common among the explicit positives, else positions within two radii."""
    if ds.positives is not None:
        from scipy.sparse import csr_matrix

        q, r = ds.positives.pairs()
        a = csr_matrix((np.ones(len(q)), (r, q)), shape=(len(ds.reference), max(1, len(ds.query))))
        return np.asarray(a[i].multiply(a[j]).sum(axis=1)).ravel() > 0
    p = np.asarray(ds.reference.positions, np.float64)
    return np.linalg.norm(p[i] - p[j], axis=1) <= 2 * ds.radius


def _stretch(a: np.ndarray, b: np.ndarray, step: int) -> tuple[tuple[int, int], tuple[int, int], int]:
    """The longest stretch of revisiting rows ``a [K]`` (rows more than 3 ``step`` apart start another) as
    ``((a0, a1), (b0, b1), stretches)``: its rows' range, their partners' ``b [K]`` range, and how many stretches."""
    order = np.argsort(a, kind="stable")
    a, b = a[order], b[order]
    cut = np.flatnonzero(np.diff(a) > 3 * step) + 1
    parts = np.split(np.arange(len(a)), cut)
    g = max(parts, key=len)
    return (int(a[g].min()), int(a[g].max()) + 1), (int(b[g].min()), int(b[g].max()) + 1), len(parts)
