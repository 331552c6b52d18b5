"""seqnet: sequence-based visual place recognition (SeqNet, SeqMatch, HVPR).

Main entry points::

    from seqnet import seqmatch, hvpr, knn, recall_at_k, SeqNet, load_dataset, evaluate
"""

from __future__ import annotations

from ._version import __version__
from .blocks import topk_smallest
from .data.io import load_dataset, save_dataset
from .data.synth import make_synthetic
from .data.traverse import Dataset, Traverse
from .distances import knn, pairwise_distances
from .errors import CheckpointError, ConfigError, DatasetError, ImageError, SeqnetError
from .evaluate import EvalConfig, Evaluation, evaluate
from .hvpr import hvpr
from .recall import recall_at_k
from .seqmatch import seqmatch
from .sequence_descriptors import SeqNet, delta, smoothing
from .windows import window_indices, window_starts

__all__ = [
    "__version__", "CheckpointError", "ConfigError", "DatasetError", "Dataset", "EvalConfig", "Evaluation",
    "ImageError", "SeqNet",
    "SeqnetError", "Traverse", "delta", "evaluate", "hvpr", "knn", "load_dataset", "make_synthetic",
    "pairwise_distances", "recall_at_k", "save_dataset", "seqmatch", "smoothing", "topk_smallest",
    "window_indices", "window_starts",
]
