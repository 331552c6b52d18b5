"""Single-image descriptors of image folders: pixels, GeM, GMP and NetVLAD, with optional PCA.

Pipeline: list images (:mod:`.images`) → :class:`DescribeConfig` (:mod:`.config`) → a method of the
:data:`DESCRIBERS` table (:mod:`.methods`; CNN backbones in :mod:`.cnn`, NetVLAD in :mod:`.netvlad`,
pixels in :mod:`.pixels`) → a fitted :class:`Describer` (:mod:`.describer`, PCA in :mod:`.pca`,
fitted-state files in :mod:`.state`) → resumable file output and the stage :func:`main` (:mod:`.store`)::

    conf = DescribeConfig(method="gem", size=(256, 128))
    desc, names = describe_images(paths, conf)                          # in memory, [N, D] float32
    desc, names = describe_folder("summer/", conf, out="summer.h5")    # resumable file output
    d = make_describer(conf.replace(dim=256), fit_paths)               # one fitted state, many traverses
"""

from .cnn import BACKBONES
from .config import DescribeConfig
from .describer import Describer, describe_images, fit_paths_of, make_describer
from .registry import DESCRIBERS
from .store import OUT_SUFFIXES, describe_folder, describe_to_file, main, names_file_for

__all__ = [
    "BACKBONES", "DESCRIBERS", "OUT_SUFFIXES", "DescribeConfig", "Describer", "describe_folder", "describe_images",
    "describe_to_file", "fit_paths_of", "main", "make_describer", "names_file_for",
]
