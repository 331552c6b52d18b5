"""seqnet: sequence-based visual place recognition (SeqNet, SeqMatch, HVPR).

Main entry points::

    from seqnet import seqmatch, hvpr, knn, recall_at_k, SeqNet, load_dataset, evaluate
"""

from __future__ import annotations

import importlib
from typing import Any

from ._version import __version__

_API: dict[str, str] = {  # public name -> the module that defines it, imported on first use (fast CLI start)
    "CheckpointError": ".core.errors",
    "ConfigError": ".core.errors",
    "DatasetError": ".core.errors",
    "ImageError": ".core.errors",
    "SeqnetError": ".core.errors",
    "load_dataset": ".data.io",
    "save_dataset": ".data.io",
    "make_synthetic": ".data.synth",
    "Positives": ".data.positives",
    "read_positives": ".data.positives",
    "Dataset": ".data.traverse",
    "Traverse": ".data.traverse",
    "EvalConfig": ".eval.config",
    "Evaluation": ".eval.evaluate",
    "evaluate": ".eval.evaluate",
    "recall_at_k": ".metrics.recall",
    "Estimate": ".localize.localizer",
    "Localizer": ".localize.localizer",
    "LocalizeConfig": ".localize.config",
    "dataset_localizer": ".localize.replay",
    "hvpr": ".matching.hvpr",
    "seqmatch": ".matching.seqmatch",
    "Reference": ".methods.protocol",
    "TraverseReference": ".reference",
    "topk_smallest": ".search.blocks",
    "knn": ".search.api",
    "pairwise_distances": ".search.knn",
    "SeqNet": ".sequence.model",
    "load_model": ".sequence.checkpoints",
    "load_models": ".sequence.checkpoints",
    "delta": ".sequence.descriptors",
    "smoothing": ".sequence.descriptors",
    "Windows": ".sequence.windows",
    "window_indices": ".sequence.windows",
    "window_starts": ".sequence.windows",
}

__all__ = ["__version__", *_API]
_PACKAGES = ("core", "security", "data", "sequence", "search", "client", "sources", "matching", "metrics", "describe",
             "methods", "reference", "report", "eval", "maps", "localize", "train", "pipelines", "serve")


def __getattr__(name: str) -> Any:
    """``seqnet.<name>`` (and ``from seqnet import <name>``): import its module when it is first asked for."""
    if name in _API:
        value = getattr(importlib.import_module(_API[name], __name__), name)
        globals()[name] = value
        return value
    if name in _PACKAGES:  # seqnet.train.train(...), seqnet.describe...: a subpackage, as after importing it
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'seqnet' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API) | set(_PACKAGES))
