"""seqnet: sequence-based visual place recognition (SeqNet, SeqMatch, HVPR).

Main entry points::

    from seqnet import seqmatch, hvpr, knn, recall_at_k, SeqNet, load_dataset, evaluate
"""

from __future__ import annotations

from ._version import __version__
from .core.errors import CheckpointError, ConfigError, DatasetError, ImageError, SeqnetError
from .data.io import load_dataset, save_dataset
from .data.synth import make_synthetic
from .data.traverse import Dataset, Traverse
from .eval.evaluate import EvalConfig, Evaluation, evaluate
from .eval.metrics.recall import recall_at_k
from .localize.localizer import Estimate, Localizer
from .localize.track import LocalizeConfig, dataset_localizer
from .matching.hvpr import hvpr
from .matching.seqmatch import seqmatch
from .reference import Reference, TraverseReference
from .search.blocks import topk_smallest
from .search.knn import knn, pairwise_distances
from .sequence.descriptors import SeqNet, delta, smoothing
from .sequence.windows import Windows, window_indices, window_starts

__all__ = [
    "__version__", "CheckpointError", "ConfigError", "DatasetError", "Dataset", "Estimate", "EvalConfig", "Evaluation",
    "ImageError", "LocalizeConfig", "Localizer", "Reference", "SeqNet", "TraverseReference", "Windows",
    "dataset_localizer",
    "SeqnetError", "Traverse", "delta", "evaluate", "hvpr", "knn", "load_dataset", "make_synthetic",
    "pairwise_distances", "recall_at_k", "save_dataset", "seqmatch", "smoothing", "topk_smallest",
    "window_indices", "window_starts",
]
