"""The frames ``seqnet localize --map`` streams: a descriptor file's rows (checked against the map's provenance),
or images described one by one by the map's describer (:func:`seqnet.localize.describing.map_describer`)."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.errors import SeqnetError
from ..core.provenance import check_same
from ..data.readers import read_descriptor_file
from ..methods.protocol import Reference
from ..security.pictures import size_mismatch
from .describing import check_known_file, check_query_dim, map_describer, pca_route, query_file_provenance

if TYPE_CHECKING:
    from ..describe.images import ImageList

Frames = Iterator[tuple[np.ndarray, float]]  # (descriptor [D], milliseconds spent describing it)


def descriptor_frames(path: Path, ref_map: Reference, allow: bool,
                      map_dir: str | Path | None = None) -> tuple[Frames, list[str] | None, int]:
    """The frames of a descriptor file (checked against the map's provenance; a file of unknown making against a
    map a PCA reduced is refused: :func:`~seqnet.localize.describing.check_known_file`), their names and count."""
    desc, names = read_descriptor_file(path)
    what, route = f"the query descriptors {path.name}", pca_route(ref_map, map_dir)
    check_query_dim(desc.shape, ref_map.input_dim, what, route)
    prov = query_file_provenance(path)
    check_known_file(prov, route, what, allow)
    try:
        check_same(ref_map.provenance, prov, "the map's descriptors", what, allow)
    except SeqnetError as e:
        if route is None:
            raise
        e.args = (f"{e}; or {route}",)
        raise
    return ((np.asarray(d), 0.0) for d in desc), names, len(desc)


def image_frames(source: Path, images: ImageList, ref_map: Reference, allow: bool, describer: str | None = None,
                 map_dir: str | Path | None = None,
                 resize: tuple[int, int] | None = None) -> tuple[Frames, list[str], int]:
    """The ``images`` of ``source`` (a folder, a list file or a bag's image topic: :func:`list_images`), each
    described when it is read by the map's describer (:func:`map_describer`; ``map_dir``: the ``--map``, ``resize``:
    ``--resize``)."""
    d, check = map_describer(ref_map, allow, describer, map_dir, resize)

    def frames() -> Frames:
        first: tuple[Any, tuple[int, ...]] | None = None
        for p in images.paths:
            t0 = time.perf_counter()
            img = d.load([p])
            if first is not None and img.shape[1:3] != first[1]:  # its D would differ: say the image and the sizes
                raise size_mismatch(p, img.shape[1:3], first[0], first[1])
            first = first or (p, img.shape[1:3])
            out = d(img)
            ms = (time.perf_counter() - t0) * 1e3
            check(out, f"the query images of {source} as described here")
            yield out[0], ms

    return frames(), images.names, len(images)
