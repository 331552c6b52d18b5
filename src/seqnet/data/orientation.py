"""Which axis of a square descriptor array holds the images: a ``[D, N]`` array saved by mistake for ``[N, D]`` is
refused by its shape unless D = N; for a square one (:func:`read_square`) the evidence is in the values.

What tells the image axis from the dimension axis, measured on nordland64 descriptors of every describer (pixels,
gem, gmp, netvlad, PCA outputs; 300 frames cropped square) and ``seqnet synth``:

* norms: every describer L2-normalises each image's descriptor, so the rows have norm 1 and the columns do not;
  cropped to fewer dimensions (or not normalised), the row norms still vary far less than the column norms (their
  coefficient of variation 0.04-0.17 against 0.25-0.95: 5.5 times or more), since dimensions differ in scale and
  images do not;
* PCA order: a PCA output's dimensions come in decreasing variance (Spearman rho of variance against index -0.92
  to -1.00); an image's variance does not fall steadily along a route.

Not used: how alike consecutive rows are (consecutive images of a traverse) against consecutive columns: adjacent
pixels are as alike as adjacent frames (nordland64 pixels: 0.50 of columns against 0.22 of rows have their nearest
at a neighbour), and the ground truth's diagonal, which both readings satisfy on aligned traverses. Evenness alone
is also what per-dimension standardisation gives (columns of mean 0): then it says nothing.
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np

from ..core.memmaps import read_rows
from ..core.memory import BLOCK_BYTES

OVERRIDE_ENV = "SEQNET_ROWS_ARE_IMAGES"  # "1": the rows of a square array are images, whatever the evidence says
OVERRIDE_KEY = "rows_are_images"  # Dataset.extra / dataset.json: the same, recorded with the dataset
MIN_SIZE = 16  # a square array smaller than this is not judged (too few rows for the statistics)
UNIT_TOL = 1e-3  # |norm - 1| of an L2-normalised row (float32 rounding is ~1e-7)
PCA_RHO = -0.9  # variance against index at most this: an axis of PCA-ordered dimensions
EVEN_WARN, EVEN_STRONG = 8.0, 3.0  # columns this many times more even than rows: suggestive / with PCA order, strong
CENTRED = 1e-3  # |column mean| under this times the column's RMS, for every column: standardised dimensions


@dataclasses.dataclass(frozen=True)
class Orientation:
    """The verdict on a square array: ``"transposed"`` (its columns look like the images), ``"rows"`` (its rows
    do), or None (undecidable); ``strong`` whether the evidence is decisive; ``why`` the evidence in words."""

    verdict: str | None
    strong: bool
    why: str


def read_square(desc: np.ndarray, block_bytes: int = BLOCK_BYTES // 4) -> Orientation:
    """The :class:`Orientation` of ``desc [N, N]`` (any other shape, or N < :data:`MIN_SIZE`: undecidable).

    Decisive: every column of L2 norm 1 and not every row (the describer normalised images that are columns),
    or the rows in PCA order (variance falling with the index) with the columns :data:`EVEN_STRONG` times more
    even in norm than the rows. Suggestive: the columns :data:`EVEN_WARN` times more even alone, or the rows in PCA
    order alone. The same evidence the other way round (unit rows, columns in PCA order) says ``"rows"``.
    One pass over ``desc`` in blocks of rows (a memory map's pages released after each)."""
    n = desc.shape[0] if desc.ndim == 2 else 0
    if desc.ndim != 2 or desc.shape[1] != n or n < MIN_SIZE:
        return Orientation(None, False, "not a square array")
    s = _sums(desc, block_bytes)
    r_norm, c_norm = np.sqrt(s["r2"]), np.sqrt(s["c2"])
    unit_r, unit_c = _unit(r_norm), _unit(c_norm)
    if unit_r != unit_c:
        which = "column" if unit_c else "row"
        return Orientation("transposed" if unit_c else "rows", True, f"every {which} has L2 norm 1 and not every "
                           f"{'row' if unit_c else 'column'}: the images were normalised as {which}s")
    rho_r, rho_c = _rho(s["r2"] / n - (s["r1"] / n) ** 2), _rho(s["c2"] / n - (s["c1"] / n) ** 2)
    pca_r, pca_c = rho_r <= PCA_RHO, rho_c <= PCA_RHO
    even = _cv(r_norm) / max(_cv(c_norm), 1e-12)  # > 1: the columns are the more even (images' norms)
    centred = bool(np.all(np.abs(s["c1"] / n) <= CENTRED * np.maximum(c_norm / np.sqrt(n), 1e-30)))
    words = (f"the row norms vary {even:.3g} times as much as the column norms (coefficient of variation), and "
             f"variance against index has Spearman rho {rho_r:.2f} along the rows, {rho_c:.2f} along the columns")
    if pca_c and not pca_r:
        return Orientation("rows", False, words)
    if pca_r and not pca_c and even >= EVEN_STRONG and not centred:
        return Orientation("transposed", True, words + " (rows in PCA order: rows are dimensions)")
    if (pca_r and not pca_c) or (even >= EVEN_WARN and not centred):
        return Orientation("transposed", False, words)
    return Orientation(None, False, words)


def overridden(extra: dict | None = None) -> bool:
    """Whether the user said the rows are images: ``extra[OVERRIDE_KEY]`` (a dataset's record) or
    ``SEQNET_ROWS_ARE_IMAGES=1`` in the environment."""
    return bool((extra or {}).get(OVERRIDE_KEY)) or os.environ.get(OVERRIDE_ENV, "") not in ("", "0")


def hint(side: str) -> str:
    """What to do about a square ``side`` (``"query"``, ``"reference"``) that reads transposed."""
    return (f"hint: save the {side} descriptors transposed, one row per image (numpy: np.save(path, x.T)); if the "
            f"rows really are images, set {OVERRIDE_ENV}=1 (Python: Dataset(..., extra={{'{OVERRIDE_KEY}': True}}), "
            "kept in dataset.json)")


def _sums(a: np.ndarray, block_bytes: int) -> dict[str, np.ndarray]:
    """Row and column sums and sums of squares of ``a [N, N]`` (float64), read in blocks of rows."""
    n = a.shape[0]
    step = max(1, block_bytes // max(1, n * 8))
    out = {"r1": np.empty(n), "r2": np.empty(n), "c1": np.zeros(n), "c2": np.zeros(n)}
    for i in range(0, n, step):
        b = np.asarray(read_rows(a, i, i + step), np.float64)
        out["r1"][i:i + len(b)], out["r2"][i:i + len(b)] = b.sum(axis=1), np.einsum("ij,ij->i", b, b)
        out["c1"] += b.sum(axis=0)
        out["c2"] += np.einsum("ij,ij->j", b, b)
    return out


def _unit(norms: np.ndarray) -> bool:
    return bool(np.all(np.abs(norms - 1.0) <= UNIT_TOL))


def _cv(x: np.ndarray) -> float:
    return float(x.std() / max(float(x.mean()), 1e-30))


def _rho(v: np.ndarray) -> float:
    """Spearman's rho of ``v [N]`` against its index (0.0 when ``v`` is constant)."""
    ranks = np.empty(len(v))
    ranks[np.argsort(v, kind="stable")] = np.arange(len(v))
    if np.ptp(v) == 0:
        return 0.0
    return float(np.corrcoef(np.arange(len(v)), ranks)[0, 1])
