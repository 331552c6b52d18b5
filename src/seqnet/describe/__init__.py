"""Single-image descriptors of image folders: pixels, GeM, GMP and NetVLAD, with optional PCA.

Pipeline: list images (:mod:`.images`) → :class:`DescribeConfig` (:mod:`.config`) → a method of the
:data:`DESCRIBERS` table (:mod:`.registry`; CNN backbones in :mod:`.cnn`, NetVLAD in :mod:`.netvlad`,
pixels in :mod:`.pixels`) → a fitted :class:`Describer` (:mod:`.describer`, PCA in :mod:`.pca`,
fitted-state files in :mod:`.state`) → resumable file output and the stage :func:`main` (:mod:`.stage`)::

    conf = DescribeConfig(method="gem", size=(256, 128))
    desc, names = describe_images(paths, conf)                          # in memory, [N, D] float32
    desc, names = describe_folder("summer/", conf, out="summer.h5")    # resumable file output
    d = make_describer(conf.replace(dim=256), fit_paths)               # one fitted state, many traverses
"""

from .cnn import BACKBONES
from .config import DescribeConfig
from .describer import Describer, describe_images, fit_paths_of, make_describer
from .merge import merge_shards
from .output import OUT_SUFFIXES, names_file_for
from .registry import DESCRIBERS
from .shards import Shard, parse_shard
from .stage import describe_folder, describe_to_file, main

__all__ = [
    "BACKBONES", "DESCRIBERS", "OUT_SUFFIXES", "DescribeConfig", "Describer", "describe_folder", "describe_images",
    "Shard", "describe_to_file", "fit_paths_of", "main", "make_describer", "merge_shards", "names_file_for",
    "parse_shard",
]
