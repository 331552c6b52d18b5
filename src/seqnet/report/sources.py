"""Whether the report's picture sources (``eval --report --images-query/--images-ref``) are the dataset's own,
the right way round: ``dataset.json`` records the image folders (``"images": {"reference", "query"}``) or the
videos (``"videos": {side: {"path"}}``) it was built from, and a folder given for the other side would show the
wrong pictures beside every example without any error; and the examples' image names as read within those folders
(:func:`inside_name`)."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ..security.text import shown

FLAGS = {"query": "--images-query", "reference": "--images-ref"}


def recorded_sources(extra: Mapping[str, Any]) -> dict[str, str]:
    """The image folder or video each side of a dataset was built from (``extra``: its dataset.json metadata),
    by side (``reference``, ``query``); sides not recorded are left out."""
    out: dict[str, str] = {}
    images, videos = extra.get("images"), extra.get("videos")
    for side in FLAGS:
        if isinstance(images, Mapping) and isinstance(images.get(side), str):
            out[side] = images[side]
        elif isinstance(videos, Mapping) and isinstance(videos.get(side), Mapping) \
                and isinstance(videos[side].get("path"), str):
            out[side] = videos[side]["path"]
    return out


def _same(a: str, b: str) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:  # either is gone: compare the resolved paths
        return Path(a).expanduser().resolve() == Path(b).expanduser().resolve()


def swapped_sources(extra: Mapping[str, Any], query_images: str | None, ref_images: str | None) -> str | None:
    """The line when ``--images-query`` is the dataset's recorded reference source or ``--images-ref`` its
    recorded query source (and not its own side's too); None otherwise or when nothing is recorded."""
    recorded, given = recorded_sources(extra), {"query": query_images, "reference": ref_images}
    other = {"query": "reference", "reference": "query"}
    wrong = [side for side, path in given.items() if path and other[side] in recorded
             and _same(path, recorded[other[side]]) and not (side in recorded and _same(path, recorded[side]))]
    if not wrong:
        return None
    said = " and ".join(f"{FLAGS[s]} {shown(given[s])} is the dataset's {other[s]} source" for s in wrong)
    fix = "swap them" if len(wrong) == 2 else "; ".join(
        f"{FLAGS[s]} {shown(recorded[s])}" for s in FLAGS if s in recorded)
    return (f"{said} (as dataset.json records it): the report's pictures would show the wrong traverse beside each "
            f"example; hint: {fix}")


def inside_name(name: str, folder: str | None) -> str:
    """``name`` relative to the image ``folder`` when it lies inside it (a list file's absolute path
    ``/data/winter/images-12420.png`` in ``/data/winter``: ``images-12420.png``), else ``name`` as the dataset
    has it."""
    if folder is None:
        return name
    try:
        return Path(os.path.abspath(name)).relative_to(os.path.abspath(folder)).as_posix()
    except ValueError:
        return name
