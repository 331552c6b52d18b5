"""The Nordland64 benchmark: real 64×32 Nordland frames, summer (reference) vs winter (query).

Pipeline (:func:`main`): list the places (frames in the clean list, present in both seasons,
ordered by frame number; position = frame number / 10) → describe the images (cached in
``OUT/dataset``) → fit a PCA on the train range → train S_L and S_1 on the train range, selecting
the epoch on the val range → fold the PCA into the models (so they read the raw descriptors) →
evaluate every method on the test range → ``results.json``, ``results.md``, ``recall_at_k.png``,
``pr_curve.png``.

Modules: :mod:`.config` (:class:`Nordland64Config`, tuned on the val range only), :mod:`.data`,
:mod:`.models`, :mod:`.run`, :mod:`.speed` (variable-speed queries), :mod:`.longer` (the
L_m = 5 / 10 / 20 comparison, :func:`longer_sequences`).
"""

from .config import Nordland64Config
from .data import build_dataset, describe_flipped, list_places, training_dataset
from .longer import longer_sequences
from .models import fold_pca, train_models
from .run import main

__all__ = ["Nordland64Config", "build_dataset", "describe_flipped", "fold_pca", "list_places", "longer_sequences",
           "main", "train_models", "training_dataset"]
