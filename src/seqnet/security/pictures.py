"""Decoding one image (a file, or a frame that opens itself) into uint8 pixels, as an untrusted input.

* Only the raster formats seqnet reads are tried (:data:`FORMATS`): PIL otherwise lets every decoder it
  has parse the bytes, whatever the file's name (an EPS file would start Ghostscript).
* A file is opened without blocking (:func:`seqnet.security.inputs.open_input`): a FIFO or device is refused.
* An image declaring more than ``max_pixels`` is refused from its header; PIL's own decompression-bomb
  check stays on, its warning an error too.
* Whatever a decoder raises on damaged bytes is one :class:`ImageError` naming the image (shown escaped).
* An image is read the way viewers show it: its EXIF orientation (a phone photo stored sideways, tag 0x0112) is
  applied (:func:`upright`), as ``PIL.ImageOps.exif_transpose`` does.
* A 16-bit image whose values never exceed 255 holds 8-bit data in a 16-bit file (as OpenCV / NumPy pipelines
  write ``uint8`` data saved as ``uint16``): it is read as 8-bit, its values as they are, and said once per folder
  (:func:`say_8_bit`). Scaled by 255/65535 as 16-bit data is, each pixel would become 0 or 1.
"""

from __future__ import annotations

import os
import struct
import warnings
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ImageError
from ..core.log import warn_once
from .inputs import open_input, special_file
from .text import shown

FORMATS = ("PNG", "JPEG", "BMP", "TIFF", "WEBP", "PPM", "GIF")  # PPM: also PGM and PBM; JPEG: also MPO
COMPRESSED_FORMATS = ("JPEG", "PNG")  # of a ROS CompressedImage
MAX_PIXELS = 100_000_000  # larger images are refused before decoding (a "decompression bomb" or a mistake)
HIGH_DEPTH_MODES = ("I;16", "I;16B", "I;16L", "I;16N", "I")  # 16-bit (and 32-bit integer) greyscale
WIDE_RGB = {"RGB;16B": "RGB;16L", "RGBA;16B": "RGBA;16L"}  # 16-bit RGB(A) PNG: PIL keeps each sample's high byte
ORIENTATION = 0x0112  # the EXIF tag a camera writes instead of rotating the pixels
# what PIL's decoders raise on damaged bytes besides OSError (seen by fuzzing PNG, JPEG, BMP, TIFF, GIF)
DECODE_ERRORS = (OSError, ValueError, SyntaxError, EOFError, struct.error, IndexError, KeyError, TypeError,
                 ZeroDivisionError, OverflowError, AttributeError, RecursionError, MemoryError, zlib.error)


def open_image(source: Any, formats: tuple[str, ...] = FORMATS) -> Any:
    """``PIL.Image.open`` of a path or file object, trying only ``formats``."""
    from PIL import Image

    return Image.open(source, formats=list(formats))


def read_image(path: Path, grey: bool = False, max_pixels: int = MAX_PIXELS) -> np.ndarray:
    """Decode one image file as uint8 ``[H, W, 3]`` (``[H, W]`` when ``grey``); :class:`ImageError` if it is
    missing, not a regular file, unreadable or larger than ``max_pixels`` (checked from the header)."""
    kind = special_file(path)
    if kind:  # opening a FIFO would wait for a writer; a device could be endless
        raise ImageError(f"image {shown(path)} is a {kind}, not a regular file; it is not opened (hint: list image "
                         "files)")
    with open_input(path, "image", ImageError) as f:  # non-blocking: what turned special since is refused too
        def opener() -> Any:
            f.seek(0)  # a second opening (:func:`low_bytes`) reads the file again
            return open_image(f)

        return decode(opener, path, grey, max_pixels)


def decode(opener: Callable[[], Any], where: Any, grey: bool = False, max_pixels: int = MAX_PIXELS) -> np.ndarray:
    """The PIL image ``opener()`` returns (opened lazily: its header first), checked against ``max_pixels``,
    loaded, turned upright and converted by :func:`to_uint8`; decoding errors are :class:`ImageError` s naming
    ``where``. A 16-bit RGB(A) PNG that reads all black (PIL keeps the high bytes) is opened again for its low
    bytes (:func:`low_bytes`): 8-bit data in a 16-bit file."""
    from PIL import Image, UnidentifiedImageError

    name = shown(where)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            with opener() as im:
                if im.width * im.height > max_pixels:
                    raise ImageError(f"image {name} is too large: it declares {im.width}x{im.height} pixels, more "
                                     f"than the limit of {max_pixels:,} (hint: --skip-corrupted leaves it out)")
                wide = WIDE_RGB.get(str(im.tile[0][3])) if im.format == "PNG" and len(im.tile) == 1 else None
                im.load()
                if wide is None or np.asarray(im).any():
                    return to_uint8(upright(im), name, grey)
            return low_bytes(opener, wide, name, grey)
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as e:
        raise ImageError(f"image {name} is too large to decode safely ({' '.join(str(e).split())[:200]}; hint: "
                         "--skip-corrupted leaves it out)") from e
    except UnidentifiedImageError as e:
        raise ImageError(f"cannot read image {name}: not an image of a format seqnet reads ({', '.join(FORMATS)}; "
                         "hint: --skip-corrupted leaves such images out)") from e
    except DECODE_ERRORS as e:
        raise ImageError(f"cannot read image {name} ({type(e).__name__}: {' '.join(str(e).split())[:200]}; hint: "
                         "--skip-corrupted leaves such images out)") from e


def low_bytes(opener: Callable[[], Any], rawmode: str, name: str, grey: bool) -> np.ndarray:
    """A 16-bit RGB(A) PNG whose high bytes are all zero, decoded again with ``rawmode`` (the low byte of each
    sample): its values 0..255 as they are (said by :func:`say_8_bit` unless they are all zero: black either way)."""
    with opener() as im:
        im.tile = [t._replace(args=rawmode) if hasattr(t, "_replace") else (*t[:3], rawmode)  # Pillow < 11: tuples
                   for t in im.tile]
        im.load()
        if np.asarray(im).any():
            say_8_bit(name, im.mode, int(np.asarray(im).max()))
        return to_uint8(upright(im), name, grey)


def say_8_bit(name: str, mode: str, hi: int) -> None:
    """Say (once per folder) that the 16-bit image ``name`` holds values 0..``hi`` <= 255 only, read as 8-bit."""
    folder = os.path.dirname(name) or "."
    warn_once(("8-bit data in 16 bits", folder), "image %s is 16-bit (%s) but its values are 0..%d only: 8-bit data "
              "saved in a 16-bit file, read as 8-bit (values kept; scaled as 16-bit data they would be 0 or 1, a "
              "near-black picture); other such images of %s are read the same way without another line", name,
              mode, hi, folder)


def upright(im: Any) -> Any:
    """The loaded PIL image ``im`` as viewers show it: its EXIF orientation applied (2..8: a mirror and/or a
    rotation by 90, 180 or 270 degrees; the same transposes as ``PIL.ImageOps.exif_transpose``); ``im`` itself
    when it has none, or when its EXIF block is unreadable (viewers then show the stored pixels too)."""
    from PIL import Image

    try:
        orientation = im.getexif().get(ORIENTATION)
    except DECODE_ERRORS:
        return im
    t = Image.Transpose
    method = {2: t.FLIP_LEFT_RIGHT, 3: t.ROTATE_180, 4: t.FLIP_TOP_BOTTOM, 5: t.TRANSPOSE, 6: t.ROTATE_270,
              7: t.TRANSVERSE, 8: t.ROTATE_90}.get(orientation)  # type: ignore[call-overload]
    return im if method is None else im.transpose(method)


def to_uint8(im: Any, path: Any, grey: bool) -> np.ndarray:
    """A decoded PIL image as uint8 ``[H, W, 3]`` (``[H, W]`` when ``grey``), scaled from its own range:
    16-bit greyscale by 255/65535 (values 0..255 only: as they are, :func:`say_8_bit`), float images in [0, 1]
    by 255 (in [0, 255] as they are); palette, CMYK, alpha (dropped) and other 8-bit modes through PIL's
    conversion. A range that cannot be
    mapped without guessing is an :class:`ImageError`."""
    if im.mode not in HIGH_DEPTH_MODES and im.mode != "F":
        return np.asarray(im.convert("L" if grey else "RGB"))
    a = np.asarray(im, dtype=np.float64)
    lo, hi = (float(a.min()), float(a.max())) if a.size else (0.0, 0.0)
    if not np.isfinite([lo, hi]).all():
        raise ImageError(f"image {path} ({im.mode}) holds NaN or inf pixels")
    if im.mode == "F" and lo >= 0 and hi <= 1:
        a = a * 255.0
    elif im.mode == "F" and not (lo >= 0 and hi <= 255):
        raise ImageError(f"float image {path} has values in [{lo:g}, {hi:g}]; seqnet reads float images in [0, 1] or "
                         "[0, 255] (hint: rescale it, or save it as 8- or 16-bit)")
    elif im.mode != "F":
        if lo < 0 or hi > 65535:
            raise ImageError(f"image {path} ({im.mode}) has values in [{lo:g}, {hi:g}], outside 16 bits")
        if 0 < hi <= 255:  # 8-bit data in a 16-bit file; divided by 257 each pixel would be 0 or 1
            say_8_bit(str(path), im.mode, int(hi))
        else:
            a = a / 257.0  # 0..65535 -> 0..255
    g = np.clip(np.round(a), 0, 255).astype(np.uint8)
    return g if grey else np.repeat(g[..., None], 3, axis=-1)


def size_mismatch(path: Any, shape: tuple[int, ...], first: Any, first_shape: tuple[int, ...]) -> ImageError:
    """The error of an image whose (prepared) size differs from the images before it: it and one of those named,
    both sizes, and the resize that brings every image to one size."""
    (h, w), (h0, w0) = shape[:2], first_shape[:2]
    return ImageError(f"image {shown(path)} has size {w}x{h} but the images before it (e.g. {shown(first)}) have "
                      f"{w0}x{h0}; images described at their native size must all have one size (hint: --resize "
                      f"{w0}x{h0}, or size=({w0}, {h0}), brings every image to one size)")
