"""The image names of a folder, in the order VPR-methods-evaluation gives its descriptor rows.

VPR-methods-evaluation (gmberton/VPR-methods-evaluation ``test_dataset.read_images_paths``) saves
``database_descriptors.npy`` / ``queries_descriptors.npy`` without names; their rows are its folder's images:

* when the list file ``<folder>_images_paths.txt`` exists (next to the folder: ``data/database`` ->
  ``data/database_images_paths.txt``), its lines (``str.splitlines``), paths relative to the folder, in
  the listed order;
* otherwise ``sorted(glob(f"{folder}/**/*", recursive=True))`` (Python's string order over the paths,
  sub-folders included, hidden files and folders skipped) keeping the files whose extension, lower-cased,
  is ``.jpg``, ``.jpeg`` or ``.png``.

seqnet follows both rules; a list line must name a file inside the folder (no absolute path, ``..``, NUL or
link leading out), which is refused naming its line, never skipped (a skipped line shifts every later row).
Positions come from VPR-methods-evaluation's UTM-coded names (:func:`parse_utm_name`).
"""

from __future__ import annotations

import glob
import os
from pathlib import Path

import numpy as np

from ..core.errors import DatasetError
from ..core.log import logger
from ..security.inputs import inside
from ..security.inputs import read_text as read_input_text
from ..security.limits import POSITION_MAX

LIST_SUFFIX = "_images_paths.txt"
IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png")
MAX_LIST = 1 << 30  # bytes of a list file read whole


def list_file(folder: Path) -> Path:
    """VPR-methods-evaluation's list file of ``folder``: ``<folder>_images_paths.txt``, beside the folder."""
    return folder.parent / (folder.name + LIST_SUFFIX)


def folder_names(folder: str | Path) -> list[str]:
    """The images of ``folder`` (paths relative to it) in VPR-methods-evaluation's order: its list file when
    there is one, else its ``.jpg`` / ``.jpeg`` / ``.png`` files by sorted recursive glob."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DatasetError(f"image folder not found: {folder}")
    _check_inner_list(folder)
    lst = list_file(folder)
    if lst.exists():
        names = _listed_names(folder, lst)
        how = f"from {lst} (VPR-methods-evaluation's list file, in its order)"
    else:
        names = _globbed_names(folder)
        how = (f"by sorted(glob('**/*')) of its .jpg/.jpeg/.png files (no list file {lst.name} beside it, "
               "VPR-methods-evaluation's rule)")
    logger.info("%s: %d image names %s", folder, len(names), how)
    return names  # checked by the caller (seqnet.data.readers.read_names)


def _check_inner_list(folder: Path) -> None:
    """Refuse ``<folder>/_images_paths.txt``: VPR-methods-evaluation reads it only when given the folder with a
    trailing ``/``, which seqnet cannot know, so the two orders it may have used are not guessed between."""
    inner = folder / LIST_SUFFIX
    if os.path.lexists(inner):
        raise DatasetError(f"{inner} exists: VPR-methods-evaluation reads it as the image list only when the folder "
                           f"is given with a trailing '/'; hint: move it to {list_file(folder)} if the descriptors "
                           "follow it, or rename it if they follow the sorted folder")


def _listed_names(folder: Path, lst: Path) -> list[str]:
    """The lines of the list file ``lst``, each a file inside ``folder`` (else an error naming the line)."""
    lines = read_input_text(lst, MAX_LIST, "image list file").splitlines()
    if not lines:
        raise DatasetError(f"{lst}: the image list file is empty")
    for i, line in enumerate(lines, start=1):
        where = f"{lst}, line {i}"
        if not line or line != line.strip():
            raise DatasetError(f"{where}: {line!r} is empty or starts or ends with whitespace; each line must be "
                               f"one image path relative to {folder}")
        path = inside(folder, line, where)
        if not path.is_file():
            raise DatasetError(f"{where}: {line!r} is not a file in {folder}; hint: the list's lines are paths "
                               "relative to the folder, in the descriptors' row order")
    return lines


def _globbed_names(folder: Path) -> list[str]:
    """The image files under ``folder`` by VPR-methods-evaluation's sorted recursive glob (relative paths:
    the folder prefix is common to all, so the order is that of the full paths)."""
    found = sorted(glob.glob("**/*", root_dir=folder, recursive=True))
    names = [p for p in found if os.path.splitext(p)[1].lower() in IMAGE_EXTENSIONS and (folder / p).is_file()]
    if not names:
        raise DatasetError(f"{folder}: no .jpg/.jpeg/.png images under it (names are read as VPR-methods-evaluation "
                           f"does: sorted(glob('**/*')), or the list file {list_file(folder)})")
    return names


def parse_utm_name(name: str) -> tuple[float, float]:
    """``(easting, northing)`` from a name like ``@0543256.96@4477929.94@17@T@...jpg``: VPR-methods-evaluation's
    ``split("@")[1]``, ``[2]`` (there of the whole path, here of the file name: an ``@`` in a folder is no field)."""
    fields = name.replace("\\", "/").rsplit("/", 1)[-1].split("@")
    try:
        easting, northing = float(fields[1]), float(fields[2])
    except (IndexError, ValueError) as err:
        raise DatasetError(f"image name {name!r} carries no UTM coordinates; expected '@<easting>@<northing>@...' "
                           "(e.g. '@0543256.96@4477929.94@17@T@...jpg')") from err
    if not abs(easting) <= POSITION_MAX >= abs(northing):  # NaN fails too
        raise DatasetError(f"image name {name!r}: UTM {fields[1]!r}, {fields[2]!r} not finite within ±{POSITION_MAX:g}")
    return easting, northing


def utm_positions(names: list[str]) -> np.ndarray:
    """``[N, 2]`` easting/northing parsed from UTM-coded image names."""
    return np.array([parse_utm_name(n) for n in names], dtype=np.float64).reshape(-1, 2)
