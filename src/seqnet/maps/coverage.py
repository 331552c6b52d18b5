"""What part of its dataset's reference traverse a map holds, said where it matters.

``seqnet index build`` maps one split's reference frames (``--split``; the test split by default when the dataset
defines one). When the splits have reference ranges of their own, that is part of the route only: ``index build``
says which frames of how many (:func:`coverage_line`), and ``seqnet localize --map`` says when the query is far
longer than such a map (:func:`partial_map_note`): its frames beyond the map's part of the route are answered with
the nearest place the map holds, which is wrong, and nothing else would say so (hunt 5: the whole 300-frame route
against the test split's 60 frames, every answer among those 60).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

LONGER = 2.0  # a query more than this many times the map's frames: more route than a part of it can hold


def _source(meta: Mapping[str, Any] | None) -> tuple[str, int, int, int | None] | None:
    """``(split, a, b, N)``: the map's split, its reference range ``a:b`` and its dataset's reference frames ``N``
    (None: not recorded, a map built before seqnet recorded it); None without a recorded range."""
    src = (meta or {}).get("source")
    src = src if isinstance(src, Mapping) else {}
    rng, total = src.get("reference_range"), src.get("dataset_reference_frames")
    if not (isinstance(rng, list | tuple) and len(rng) == 2 and all(isinstance(x, int) for x in rng)):
        return None
    return str(src.get("split")), int(rng[0]), int(rng[1]), total if isinstance(total, int) else None


def coverage_line(meta: Mapping[str, Any] | None, split_given: bool = True) -> str | None:
    """One line: which reference frames of its dataset the map holds, and the flag that maps them all when it holds
    part of them (``split_given``: ``--split`` was given; else the split is said to be the default)."""
    got = _source(meta)
    if got is None:
        return None
    split, a, b, total = got
    name = (meta or {}).get("source", {}).get("dataset", "its dataset")
    how = "" if split_given or split == "all" else " (no --split: the test split, the default)"
    if total is not None and b - a >= total:
        return f"reference: all {total} frames of dataset {name}" + (f", the {split} split's{how}" if split != "all"
                                                                    else "")
    of = f"{b - a} of the {total}" if total is not None else f"{b - a}"
    return (f"reference: the {split} split's frames {a}:{b}, {of} of dataset {name}{how}; a query along the rest of "
            "the route is answered among these: map every frame with --split all")


def partial_map_note(meta: Mapping[str, Any] | None, map_name: str, query_frames: int) -> str | None:
    """A line when the map holds part of its dataset's reference (one split's range) and the query has more than
    :data:`LONGER` times its frames, else None."""
    got = _source(meta)
    if got is None:
        return None
    split, a, b, total = got
    if total is None or b - a >= total or query_frames <= LONGER * (b - a):
        return None
    return (f"the query has {query_frames} frames, {query_frames / (b - a):.1f} times the map's {b - a}: map "
            f"{map_name} holds only the {split} split's reference frames {a}:{b} of the {total} of its dataset, so "
            "query frames beyond that part of the route are answered with the nearest place it holds (wrong, "
            "whatever the confidence); to localise along the whole route, build the map with seqnet index build "
            "--split all")
