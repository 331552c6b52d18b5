"""Mistakes in a dataset that every command would accept and score: found when the dataset is built
(``seqnet dataset from-images``) and by ``seqnet dataset check``.

* :func:`check_frame_aligned`: frame-aligned ground truth (query frame i shows the place of reference frame
  i) with traverses of different lengths, or with image names that do not pair up (a missing image shifts
  the ground truth of every later frame): refused.
* :func:`dataset_warnings` (logged by :func:`review`): the query images are the reference images (every metric
  trivially perfect), splits that share queries (selection and test numbers optimistic), positions all within
  the radius of each other (constant GPS, or degrees: every reference is correct, R@K trivially 1), rows not in
  route order (:func:`seqnet.data.spacing.out_of_order`), exact duplicate rows of either side
  (:func:`duplicated_rows`), square positives that read better transposed (:func:`.truth.transposed_positives`), a
  frame radius as wide as a metres one (:func:`.truth.wide_frame_radius`), a frozen GPS fix
  (:func:`.truth.frozen_positions`), the reference's positions given for the query too
  (:func:`.positions.copied_positions`), a reference that passes places twice unknown to the ground truth
  (:func:`.revisits.revisited_reference`), a vehicle standing still, positions that jump inside a sequence and a
  radius below the reference's frame spacing or at a multiple of it that rounding decides
  (:func:`.route.route_checks`), square descriptors that may be
  ``[D, N]`` (:func:`transposed_descriptors`), rows that share a common offset far beyond their spread
  (:func:`.values.narrow_directions`), a query whose descriptors are not comparable with the reference's (two
  models, a PCA per traverse: :func:`.spaces.separate_pcas`, :func:`.spaces.foreign_spaces`). One line each.
"""

from __future__ import annotations

from collections.abc import Sequence

from ...core.errors import DatasetError
from ...core.log import logger
from ..order import natural_key
from ..orientation import hint as orientation_hint
from ..orientation import overridden, read_square
from ..spacing import out_of_order
from ..traverse import Dataset
from .copies import copied_queries, duplicated_rows
from .positions import copied_positions
from .revisits import revisited_reference
from .route import route_checks
from .spaces import foreign_spaces, separate_pcas
from .truth import (
    constant_positions,
    degree_positions,
    frozen_positions,
    matrix_as_descriptors,
    shared_queries,
    transposed_positives,
    unmatched_splits,
    wide_frame_radius,
)
from .values import narrow_directions

__all__ = ["ALIGNED_TRUTHS", "ALTERNATIVES", "VIDEO_ALTERNATIVES", "check_frame_aligned",
           "copied_queries", "dataset_warnings", "duplicated_rows", "frozen", "real_positions", "review", "route_order",
           "shared_queries", "transposed_descriptors"]

ALTERNATIVES = ("give the ground truth another way: --positives FILE (per query its matching reference indices) "
                "or positions (--ref-csv / --query-csv, --utm-names)")


VIDEO_ALTERNATIVES = ("give positions for both videos (--ref-positions / --query-positions FILE: GPX, NMEA or "
                      "CSV tracks), or use two videos of equal length and frame rate")
ALIGNED_TRUTHS = ("frames", "aligned")  # recorded ground truths of frame-aligned traverses: from-images, from-video


def check_frame_aligned(ref_names: Sequence[str], query_names: Sequence[str], where: str = "--frame-aligned",
                        by_name: bool = True, hint: str = ALTERNATIVES) -> str | None:
    """Raise :class:`DatasetError` unless query frame i can be the place of reference frame i: as many frames
    on both sides and, when ``by_name`` and the two traverses name their images alike (some names in common),
    the same name at every index (video frames, named by their time, are compared by count only). Names are
    compared by their :func:`~seqnet.data.order.natural_key` (numbers by value, letters in any case): ``img1.png``
    pairs with ``img001.png``; returned is then a line that says so (else None)."""
    n_r, n_q = len(ref_names), len(query_names)
    if n_r != n_q:
        raise DatasetError(f"{where}: query frame i is the place of reference frame i, but the reference has {n_r} "
                           f"images and the query {n_q}, so the ground truth cannot line up; hint: {hint}")
    if not by_name:
        return None
    keys_r, keys_q = [tuple(natural_key(n)) for n in ref_names], [tuple(natural_key(n)) for n in query_names]
    if not set(keys_r) & set(keys_q):
        return None  # named differently (two cameras, two clocks): nothing to pair by name
    for i, (r, q) in enumerate(zip(ref_names, query_names, strict=True)):
        if keys_r[i] != keys_q[i]:
            raise DatasetError(f"{where}: reference image {i} is {r!r} but query image {i} is {q!r}: an image "
                               "missing from one folder shifts every later frame and the ground truth would no "
                               f"longer line up; fix or remove them so both folders hold the same names, or "
                               f"{ALTERNATIVES}")
    odd = next((i for i, (r, q) in enumerate(zip(ref_names, query_names, strict=True)) if r != q), None)
    if odd is None:
        return None
    return (f"{where}: the names differ only in zero-padding or case (reference {ref_names[odd]!r}, query "
            f"{query_names[odd]!r}): paired by their numbers")


def review(ds: Dataset) -> list[str]:
    """Check ``ds`` as built: frame-aligned ground truth (recorded as ``"ground_truth"`` ``"frames"`` or, from
    videos, ``"aligned"``: :data:`ALIGNED_TRUTHS`) must pair up (:func:`check_frame_aligned`, else
    :class:`DatasetError`); every :func:`dataset_warnings` line is logged as a warning, and returned."""
    truth = ds.extra.get("ground_truth")
    if truth in ALIGNED_TRUTHS:
        video = truth == "aligned"  # frames named by their video time: the counts must match, not the names
        check_frame_aligned(ds.reference.names, ds.query.names, f"{ds.name}: frame-aligned ground truth",
                            by_name=not video, hint=VIDEO_ALTERNATIVES if video else ALTERNATIVES)
    found = dataset_warnings(ds)
    for line in found:
        logger.warning("%s", line)
    return found


def dataset_warnings(ds: Dataset) -> list[str]:
    """One line per likely mistake in ``ds`` (none: an empty list): see the module's description."""
    found = [copied_queries(ds), shared_queries(ds, list(ds.splits)), constant_positions(ds), *route_order(ds),
             duplicated_rows(ds.query.descriptors, "query"), duplicated_rows(ds.reference.descriptors, "reference"),
             transposed_positives(ds), wide_frame_radius(ds), degree_positions(ds), unmatched_splits(ds),
             matrix_as_descriptors(ds), *transposed_descriptors(ds), *frozen(ds), copied_positions(ds),
             revisited_reference(ds), *route_checks(ds), narrow_directions(ds), separate_pcas(ds) or foreign_spaces(ds)]
    return [f"{ds.name}: {line}" for line in found if line]


def transposed_descriptors(ds: Dataset) -> list[str]:
    """A line for each square ``[N, N]`` descriptor array of ``ds`` whose values suggest, short of deciding, that it
    is ``[D, N]`` (:func:`seqnet.data.orientation.read_square`; decisive evidence is refused when the dataset is
    made); none when the user said the rows are images (:func:`seqnet.data.orientation.overridden`)."""
    if overridden(ds.extra):
        return []
    found = []
    for side, t in (("reference", ds.reference), ("query", ds.query)):
        o = read_square(t.descriptors)
        if o.verdict == "transposed" and not o.strong:
            found.append(f"the {side} descriptors are square ([{len(t)}, {len(t)}]), so their shape cannot say "
                         f"which axis holds the images, and they may be transposed ([D, N]): {o.why}; "
                         f"{orientation_hint(side)}")
    return found


def frozen(ds: Dataset) -> list[str]:
    """The :func:`frozen_positions` lines of the query and the reference of ``ds``, when positions decide what is
    correct (real positions, no explicit positives, not all within the radius: :func:`constant_positions`)."""
    if ds.positives is not None or ds.position_unit == "frames" or constant_positions(ds):
        return []
    found = [frozen_positions(t.positions, t.descriptors, side) for side, t in (("query", ds.query),
                                                                                 ("reference", ds.reference))]
    return [line for line in found if line]


def real_positions(ds: Dataset) -> bool:
    """Whether ``ds``'s positions say how far frames are apart (not the frame numbers that stand in for positions
    beside explicit positives)."""
    return ds.positives is None or ds.position_unit != "frames"


def route_order(ds: Dataset) -> list[str]:
    """The :func:`seqnet.data.spacing.out_of_order` lines of the query and the reference of ``ds`` (none when
    its positions are frame numbers: :func:`real_positions`)."""
    if not real_positions(ds):
        return []
    found = [out_of_order(t.positions, t.seq_bounds, ds.radius, ds.position_unit, side, t.names is not None)
             for side, t in (("query", ds.query), ("reference", ds.reference))]
    return [line for line in found if line]


