"""seqnet: sequence-based visual place recognition (SeqNet, SeqMatch, HVPR).

Main entry points::

    from seqnet import seqmatch, hvpr, knn, recall_at_k, SeqNet, load_dataset, evaluate
"""

from __future__ import annotations

__version__ = "0.1.0"

from .dataset_io import load_dataset, save_dataset
from .errors import CheckpointError, ConfigError, DatasetError, ImageError, SeqnetError
from .evaluate import Evaluation, evaluate
from .matching import knn, pairwise_distances, topk_smallest
from .recall import recall_at_k
from .sequence_descriptors import SeqNet, delta, smoothing
from .sequence_matching import hvpr, seqmatch
from .synth import make_synthetic
from .traverse import Dataset, Traverse
from .windows import window_indices, window_starts

__all__ = [
    "CheckpointError", "ConfigError", "DatasetError", "Dataset", "Evaluation", "ImageError", "SeqNet",
    "SeqnetError", "Traverse", "delta", "evaluate", "hvpr", "knn", "load_dataset", "make_synthetic",
    "pairwise_distances", "recall_at_k", "save_dataset", "seqmatch", "smoothing", "topk_smallest",
    "window_indices", "window_starts",
]
