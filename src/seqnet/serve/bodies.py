"""Request bodies as untrusted input: one descriptor (``application/x-npy``) or one image (``image/png``,
``image/jpeg``, ``image/webp``), read through :mod:`seqnet.security`.

* A descriptor's ``.npy`` header is parsed by :func:`seqnet.security.arrays.read_header` (bounded, no pickle:
  :func:`~seqnet.security.arrays.check_dtype` admits floating point numbers only); its shape must be ``[D]`` and
  its data exactly the bytes the header declares (fewer: truncated, more: trailing bytes).
* An image is decoded by :func:`seqnet.security.pictures.decode` (only the format its content type names; more
  than :data:`MAX_PIXELS` refused from the header, before decoding), through the describer's own loader
  (:func:`load_image`). A refusal says what the body is, for an HTTP client: empty, an image of another format
  than its content type names (which format, and the type to send it as), or damaged.
* The body itself is bounded while it is read (:func:`read_limited`), never after.
"""

from __future__ import annotations

import io
from collections.abc import AsyncIterator
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import ImageError
from ..security.arrays import check_dtype, nbytes_of, read_header
from ..security.pictures import FORMATS, open_image
from .errors import BAD_REQUEST, TOO_LARGE, UNSUPPORTED, HttpError

if TYPE_CHECKING:
    from ..describe.describer import Describer
    from ..localize.describing import ReducedDescriber

DESCRIPTOR_TYPE = "application/x-npy"
IMAGE_TYPES = {"image/png": "PNG", "image/jpeg": "JPEG", "image/webp": "WEBP"}  # content type -> the decoder tried
SENT_AS = {fmt: kind for kind, fmt in IMAGE_TYPES.items()}
MAX_PIXELS = 4096 * 4096  # an uploaded image declaring more is refused from its header (a camera frame is less)


class BadBody(HttpError):
    """A body that cannot be read as what its content type says (400)."""

    def __init__(self, message: str) -> None:
        super().__init__(BAD_REQUEST, message)


def content_type(header: str | None) -> str:
    """The media type of a ``Content-Type`` header (parameters dropped, lower case); 415 unless seqnet reads it."""
    kind = (header or "").split(";", 1)[0].strip().lower()
    if kind != DESCRIPTOR_TYPE and kind not in IMAGE_TYPES:
        raise HttpError(UNSUPPORTED, f"content type {kind[:80] or '(none)'!r} is not read here; send "
                        f"{DESCRIPTOR_TYPE} (one descriptor [D] float32) or {', '.join(IMAGE_TYPES)}")
    return kind


async def read_limited(chunks: AsyncIterator[bytes], declared: str | None, limit: int) -> bytes:
    """The body from its ``chunks``, refused (413) as soon as it exceeds ``limit`` bytes: from its declared
    ``Content-Length`` before a byte is read, else while it arrives."""
    if declared is not None:
        try:
            size = int(declared)
        except ValueError as e:
            raise BadBody(f"Content-Length {declared[:40]!r} is not a number") from e
        if size > limit:
            raise HttpError(TOO_LARGE, f"the body declares {size} bytes, more than the limit of {limit}")
    parts, n = [], 0
    async for chunk in chunks:
        n += len(chunk)
        if n > limit:
            raise HttpError(TOO_LARGE, f"the body is larger than the limit of {limit} bytes")
        parts.append(chunk)
    return b"".join(parts)


def read_descriptor(body: bytes, dim: int) -> np.ndarray:
    """One descriptor ``[dim]`` float32 from the bytes of a ``.npy`` array of shape ``[D]`` (floating point)."""
    f = io.BytesIO(body)
    shape, _, dtype = read_header(f, "the body", BadBody)
    check_dtype(dtype, "the body", BadBody, kinds="f")
    if len(shape) != 1:
        raise BadBody(f"the frame has shape {list(shape)}; send one descriptor of shape [{dim}]")
    need, have = nbytes_of(shape, dtype), len(body) - f.tell()
    if need != have:
        raise BadBody(f"the frame's header declares {need} bytes of data but the body holds {have}")
    if shape[0] != dim:
        raise BadBody(f"dimension mismatch: the frame has D={shape[0]}, the map D={dim}")
    with np.errstate(over="ignore"):  # float64 beyond float32's range: inf, refused by the localiser
        return np.frombuffer(body, dtype=dtype, count=shape[0], offset=f.tell()).astype(np.float32)


class UploadError(ImageError):
    """An uploaded image refused with a message already phrased for an HTTP client."""


class ImageBytes:
    """An uploaded image as a :class:`seqnet.describe.images.ImageItem`: decoded by the describer's loader
    (:func:`seqnet.security.pictures.decode`) as an image file is, only with the decoder of its content type."""

    def __init__(self, data: bytes, kind: str, name: str = "upload") -> None:
        self.data, self.format, self._name = data, IMAGE_TYPES[kind], name

    @property
    def name(self) -> str:
        return self._name

    def key(self) -> str:
        return self._name

    def open(self):  # noqa: ANN201 - a PIL image (PIL is imported lazily)
        from PIL import UnidentifiedImageError

        if not self.data:
            raise UploadError(f"the body is empty: send one image ({', '.join(IMAGE_TYPES)}) or one descriptor "
                             f"({DESCRIPTOR_TYPE})")
        try:
            im = open_image(io.BytesIO(self.data), (self.format,))
        except UnidentifiedImageError as e:
            raise UploadError(self.mislabelled()) from e
        if im.width * im.height > MAX_PIXELS:
            im.close()
            raise ImageError(f"the image declares {im.width}x{im.height} pixels, more than the limit of "
                             f"{MAX_PIXELS:,}")
        return im

    def mislabelled(self) -> str:
        """Why a body that is not a readable image of its content type's format was refused: what it is instead."""
        from PIL import UnidentifiedImageError

        kind = SENT_AS[self.format]
        try:
            with open_image(io.BytesIO(self.data), FORMATS) as im:
                actual = str(im.format)
        except (UnidentifiedImageError, OSError, ValueError):
            return (f"the body is not a {self.format} image (Content-Type {kind}) nor an image of another format: "
                    f"send one image ({', '.join(IMAGE_TYPES)}) or one descriptor ({DESCRIPTOR_TYPE})")
        if actual in SENT_AS:
            return f"the body is a {actual} image but its Content-Type says {kind}: send it as {SENT_AS[actual]}"
        return (f"the body is a {actual} image, which this server does not read: convert it to PNG, JPEG or WEBP "
                f"and send it as {', '.join(IMAGE_TYPES)}")

    def __str__(self) -> str:
        return self._name


def load_image(describer: Describer | ReducedDescriber, body: bytes, kind: str) -> np.ndarray:
    """The image of ``body`` (content type ``kind``) as the map's ``describer`` loads it: uint8 ``[1, H, W(, 3)]``
    (cropped and resized as the map's images were); a body that cannot be read is a :class:`BadBody` saying why,
    for an HTTP client (no command-line hint)."""
    try:
        return describer.load([ImageBytes(body, kind)])
    except ImageError as e:
        cause = e.__cause__
        if isinstance(e, UploadError) or cause is None:  # said here, or by the loader about the decoded pixels
            raise BadBody(str(e)) from e
        raise BadBody(f"cannot decode the body as {IMAGE_TYPES[kind]} ({type(cause).__name__}: "
                      f"{' '.join(str(cause).split())[:160]}): a damaged or truncated image? send the whole "
                      "file") from e
