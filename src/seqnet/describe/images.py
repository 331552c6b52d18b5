"""Listing and loading images of a folder, of a list file, or of a ROS bag's image topic.

A *source* is either a folder (its images with a known extension, in natural sort order, so
``img-2.png`` comes before ``img-10.png``), a text file with one image path per line (relative
paths are relative to the list file's folder; blank lines and ``#`` comments are ignored), or a ROS bag
with an image topic (:mod:`seqnet.sources.bags.images`: its frames in timestamp order). An image of a source is a
``Path`` or an :class:`ImageItem` (a frame that decodes itself); every reader goes through :func:`read_any`.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from ..core.errors import ConfigError, DatasetError, ImageError
from ..core.log import logger
from ..data.order import name_order, text_order_line
from ..data.readers import check_names
from ..security.inputs import read_text, special_file
from ..security.pictures import decode, read_image, size_mismatch
from ..security.text import shown
from .folders import empty_folder_hint, say_left_out

if TYPE_CHECKING:
    from ..sources.bags.positions import Positions

# the file extensions of the formats seqnet reads (seqnet.security.pictures.FORMATS; PPM: also PGM and PBM). Wider
# than seqnet.data.imagefolders.IMAGE_EXTENSIONS, which is VPR-methods-evaluation's rule for which files its
# descriptor rows are (.jpg/.jpeg/.png), followed there to pair rows with images, not to read them.
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".ppm", ".pgm", ".pbm", ".tif", ".tiff", ".webp", ".gif")
MAX_LIST = 1 << 30  # bytes of an image list file
MAX_SIDE = 8192  # largest accepted resize width or height (and image size stored in a checkpoint)


@runtime_checkable
class ImageItem(Protocol):
    """An image that is not a file of its own (a frame of a bag): it has a ``name``, ``open()`` returns it as a
    PIL image (decoded from there as an image file is: :func:`decode`), and ``key()`` identifies it in provenance
    hashes."""

    @property
    def name(self) -> str: ...

    def open(self) -> Any: ...

    def key(self) -> str: ...


ImageRef = Path | ImageItem  # one image of a source


def as_image(item: str | os.PathLike[str] | ImageItem) -> ImageRef:
    """An :class:`ImageItem` as it is, anything else as a ``Path``."""
    return item if isinstance(item, ImageItem) else Path(item)


def image_key(item: str | os.PathLike[str] | ImageItem) -> str:
    """What identifies an image in a provenance hash: its resolved path, or an item's ``key()``."""
    return item.key() if isinstance(item, ImageItem) else str(Path(item).resolve())


def read_any(item: ImageRef, grey: bool = False) -> np.ndarray:
    """Decode an image file (:func:`read_image`) or an :class:`ImageItem` as uint8 ``[H, W, 3]`` (``[H, W]``)."""
    return decode(item.open, item, grey) if isinstance(item, ImageItem) else read_image(Path(item), grey=grey)


@dataclasses.dataclass
class ImageList:
    """Images of a source and the names they are reported under (path relative to the folder/list file; a bag
    frame's timestamp)."""

    paths: list[ImageRef]
    names: list[str]
    positions: Positions | None = None  # a bag's positions topic, when one was named

    def __len__(self) -> int:
        return len(self.paths)


def list_images(source: str | Path, topic: str | None = None, positions_topic: str | None = None,
                fps: float | None = None) -> ImageList:
    """The images of a folder, a list file, the image ``topic`` of a ROS bag (and the positions of its
    ``positions_topic``, read in the same pass) or the frames of a video file (``fps`` per second of video, or
    every frame: :mod:`seqnet.sources.video`), in order; raise :class:`ImageError` when there are none."""
    from ..sources.bags.positions import BAG_SUFFIXES, is_bag
    from ..sources.video import is_video

    src = Path(source)
    if is_video(src) and topic is None and positions_topic is None:
        from ..sources.video import video_images

        return ImageList(*video_images(src, fps))
    if fps is not None:
        raise ConfigError(f"--fps {fps:g} goes with a video file, but {src} is not one (a video ends in .mp4, .mov, "
                          ".mkv, .avi, ...)")
    if is_bag(src) or (topic is not None and src.suffix.lower() in BAG_SUFFIXES):
        from ..sources.bags.images import bag_images

        return ImageList(*bag_images(src, topic, positions_topic))
    for flag, value in (("--topic", topic), ("--positions-topic", positions_topic)):
        if value is not None:
            raise ConfigError(f"{flag} {value} goes with a ROS bag (a .bag file or a ROS 2 bag directory), but {src} "
                              "is not one")
    if src.is_dir():
        entries = list(src.iterdir())
        files = [p for p in entries if p.suffix.lower() in IMAGE_EXTENSIONS and not p.name.startswith(".")]
        say_left_out(src, [p for p in entries if p.suffix.lower() not in IMAGE_EXTENSIONS or p.name.startswith(".")],
                     IMAGE_EXTENSIONS)
        odd = next((p for p in files if not p.is_file()), None)
        if odd is not None:  # left out, it would shift every frame after it (frame-aligned ground truth)
            kind = special_file(odd) or ("broken link" if odd.is_symlink() else "directory")
            raise ImageError(f"{shown(odd)} is a {kind}, not an image file; remove or rename it (images are paired by "
                             "their order in the folder)")
        files = [files[i] for i in name_order([p.name for p in files])]  # decimal names by value
        if not files:
            raise ImageError(f"no images in folder {src} (looked for {', '.join(IMAGE_EXTENSIONS)}; "
                             f"{empty_folder_hint(src, IMAGE_EXTENSIONS)})")
        return ImageList(paths=files, names=_checked([p.name for p in files], src))
    if src.exists():
        return _read_list_file(src)
    raise ImageError(f"image folder or list file not found: {src}")


def _read_list_file(src: Path) -> ImageList:
    if src.suffix.lower() in IMAGE_EXTENSIONS:
        return ImageList(paths=[src], names=[src.name])
    try:
        lines = read_text(src, MAX_LIST, "image list file", ImageError).removeprefix("\ufeff").splitlines()
    except ImageError as err:
        if "not UTF-8" not in str(err):
            raise
        raise ImageError(f"{src} is neither a folder, an image nor a text list of image paths ({err}); hint: a "
                         "list in another encoding (Windows-1252, Latin-1)? Save it as UTF-8") from err
    listed = [(n, s.strip()) for n, s in enumerate(lines, start=1) if s.strip() and not s.strip().startswith("#")]
    if not listed:
        raise ImageError(f"list file {src} names no images (expected one image path per line)")
    first: dict[str, int] = {}
    for n, name in listed:
        if name in first:
            raise ImageError(f"{src}, line {n}: '{shown(name)}' is listed again (first on line {first[name]}); each "
                             "image is listed once (hint: remove the duplicate line)")
        first[name] = n
    names = [_forward_slashes(src, n, name) for n, name in listed]
    paths = [Path(n) if Path(n).is_absolute() else src.parent / n for n in names]
    if names != [name for _, name in listed]:
        logger.info("%s: paths written with backslashes (Windows) read with '/'", src)
    if said := text_order_line(names, f"image list {src}"):  # an ls of unpadded numbers: the route scrambled
        logger.warning("%s", shown(said))
    return ImageList(paths=paths, names=_checked(names, src))


def _forward_slashes(src: Path, line: int, name: str) -> str:
    """A listed ``name`` as it is, or with ``\\`` read as ``/`` (a list written on Windows) when only that is a
    file; a backslash path that is neither: :class:`ImageError`, with the hint."""
    if "\\" not in name or (src.parent / name).exists():
        return name
    slashed = name.replace("\\", "/")
    if (src.parent / slashed).exists():
        return slashed
    raise ImageError(f"{src}, line {line}: image not found: '{shown(name)}' (nor with '/' for its backslashes); hint: "
                     "a Windows path? List the images relative to the list file's folder, with '/'")


def _checked(names: list[str], src: Path) -> list[str]:
    """Names that round-trip through a names file (no line separators) and are unique, else :class:`ImageError`."""
    try:
        return check_names(names, f"images of {src}")
    except DatasetError as e:
        raise ImageError(f"{e} (hint: rename the file)") from e


def prepare_image(
    img: np.ndarray, size: tuple[int, int] | int | None = None, crop_bottom: int = 0, path: ImageRef | None = None
) -> np.ndarray:
    """Crop ``crop_bottom`` rows off the bottom (e.g. a car bonnet), then resize to ``size=(W, H)``
    (an int W: width W and the height that keeps the aspect ratio)."""
    from PIL import Image

    if crop_bottom:
        if crop_bottom >= img.shape[0]:
            raise ImageError(f"crop-bottom {crop_bottom} removes all {img.shape[0]} rows of image {path}")
        img = img[: img.shape[0] - crop_bottom]
    if isinstance(size, int):
        size = (size, max(1, round(size * img.shape[0] / img.shape[1])))
    if size is not None and (img.shape[1], img.shape[0]) != tuple(size):
        warn_stretch(img.shape[1], img.shape[0], int(size[0]), int(size[1]))
        img = np.asarray(Image.fromarray(img).resize(tuple(int(v) for v in size), Image.BILINEAR))
    return img


ASPECT_TOLERANCE = 0.10  # a resize changing the aspect ratio by more than this is said (once per sizes)


@functools.lru_cache(maxsize=64)
def warn_stretch(w: int, h: int, to_w: int, to_h: int) -> bool:
    """Warn (once per pair of sizes) when resizing ``w x h`` images to ``to_w x to_h`` stretches them: their
    aspect ratio changes by more than :data:`ASPECT_TOLERANCE`. Returns whether it warned."""
    before, after = w / h, to_w / to_h
    if abs(after / before - 1) <= ASPECT_TOLERANCE:
        return False
    logger.warning("resizing %dx%d images to %dx%d changes their aspect ratio from %.2f to %.2f (they are "
                   "stretched); to keep it: --resize keep-aspect:%d (width %d, the height that keeps the ratio) or "
                   "--resize native", w, h, to_w, to_h, before, after, to_w, to_w)
    return True


def load_images(
    paths: Sequence[ImageRef],
    size: tuple[int, int] | int | None = None,
    crop_bottom: int = 0,
    grey: bool = False,
    skip_corrupted: bool = False,
) -> tuple[np.ndarray, list[int]]:
    """Load images into one uint8 array ``[N, H, W, 3]`` (``[N, H, W]`` when ``grey``).

    Args:
        paths: image files or :class:`ImageItem` s.
        size: ``(W, H)`` to resize to after cropping, an int W (width W keeping the aspect ratio), or
            None (the native size); the results must all have one size.
        crop_bottom: rows removed from the bottom of each image before resizing.
        grey: decode as greyscale.
        skip_corrupted: leave unreadable images out instead of raising.

    Returns:
        ``(images, skipped)`` where ``skipped`` lists the indices (into ``paths``) left out.
    """
    if isinstance(size, int) and not isinstance(size, bool):
        if size < 1:
            raise ConfigError(f"image width must be >= 1, got {size}")
    elif size is not None and (len(size) != 2 or min(size) < 1):
        raise ConfigError(f"image size must be (width, height) with both >= 1, got {size}")
    if crop_bottom < 0:
        raise ConfigError(f"crop-bottom must be >= 0 rows, got {crop_bottom}")
    out: list[np.ndarray] = []
    skipped: list[int] = []
    first: ImageRef | None = None
    for i, p in enumerate(paths):
        try:
            img = read_any(as_image(p), grey=grey)
        except ImageError:
            if not skip_corrupted:
                raise
            skipped.append(i)
            continue
        img = prepare_image(img, size, crop_bottom, p)
        if out and img.shape != out[0].shape:
            raise size_mismatch(p, img.shape, first, out[0].shape)
        first = first or p
        out.append(img)
    if not out:
        shape = (0, *(size[::-1] if isinstance(size, tuple) else (0, 0))) + (() if grey else (3,))
        return np.zeros(shape, dtype=np.uint8), skipped
    return np.stack(out), skipped


def iter_batches(n: int, batch_size: int, todo: np.ndarray | None = None) -> Iterator[np.ndarray]:
    """Index batches ``[b]`` over ``range(n)`` (only where ``todo`` is True, when given)."""
    if batch_size < 1:
        raise ConfigError(f"batch size must be >= 1, got {batch_size}")
    idx = np.arange(n) if todo is None else np.flatnonzero(todo)
    for s in range(0, idx.size, batch_size):
        yield idx[s : s + batch_size]


def sides_size_mismatch(ref: Sequence[ImageRef], query: Sequence[ImageRef], size: Any) -> ImageError | None:
    """The error when the reference and query images differ in size (their first images, e.g. two cameras) and
    ``size`` (the describer's resolved resize; None: native) keeps each at its own size: their descriptors would
    differ in length; None when they agree, when ``size`` brings both to one size, or when either side is empty."""
    if size is not None or not ref or not query:
        return None
    (h0, w0), (h1, w1) = (read_any(as_image(s[0]), grey=True).shape[:2] for s in (ref, query))
    if (h0, w0) == (h1, w1):
        return None
    return ImageError(f"the first reference image is {w0}x{h0} and the first query image {w1}x{h1} (native size): "
                      f"their descriptors would differ in length; give --resize {w0}x{h0}")
