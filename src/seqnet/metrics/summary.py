"""A JSON-ready summary of a dataset: sizes, dimensions, radius, sequence bounds and how many queries have a
true match (``seqnet dataset check`` / ``info``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..data.traverse import Dataset, Traverse
from .recall import has_positive


def summarize_dataset(ds: Dataset) -> dict[str, Any]:
    """A JSON-ready summary of a dataset: sizes, dims, radius, true-match counts, sequence bounds.

    ``queries_with_match`` counts the query images with a reference within the radius, or with
    explicit positives when the dataset has them (over the whole dataset and within each split).
    """
    def side(t: Traverse) -> dict[str, Any]:
        out: dict[str, Any] = {"images": len(t), "dim": t.dim}
        if t.seq_bounds is not None:
            lengths = np.diff(np.unique(t.seq_bounds, axis=0), axis=1).ravel()
            out["sequences"] = {"count": int(lengths.size), "min_len": int(lengths.min()),
                                "median_len": float(np.median(lengths)), "max_len": int(lengths.max())}
        return out

    def matches(d: Dataset) -> int:
        if d.positives is not None:
            return int((d.positives.counts() > 0).sum())
        return int(has_positive(d.query.positions, d.reference.positions, d.radius).sum())

    summary: dict[str, Any] = {
        "name": ds.name, "radius": ds.radius, "position_unit": ds.position_unit,
        "ground_truth": "explicit positives" if ds.positives is not None else f"radius {ds.radius:g} (inclusive)",
        "reference": side(ds.reference), "query": side(ds.query),
        "queries_with_match": matches(ds), "splits": {},
        "metadata": dict(ds.extra),
    }
    for split, rng in ds.splits.items():
        summary["splits"][split] = {"reference": list(rng["reference"]), "query": list(rng["query"]),
                                    "queries_with_match": matches(ds.split(split))}
    return summary
