"""Training SeqNet with a triplet loss (see docs/training.md).

Modules: :mod:`~seqnet.train.config` (settings), :mod:`~seqnet.train.mining` (triplets),
:mod:`~seqnet.train.losses`, :mod:`~seqnet.train.run` (run state and files),
:mod:`~seqnet.sequence.checkpoints` (model files), :mod:`~seqnet.train.epoch` (one epoch),
:mod:`~seqnet.train.loop` (:func:`train`, the stage :func:`main`), :mod:`~seqnet.train.distributed`
(torchrun: process group, ranks, collectives).
"""

from .config import TrainConfig
from .loop import main, train
from .run import Run

__all__ = ["Run", "TrainConfig", "main", "train"]
