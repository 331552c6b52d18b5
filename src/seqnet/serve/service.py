"""The map a server shares: loaded once, as ``seqnet localize --map`` loads it, and what a frame becomes.

:func:`load_service` loads the models and the map with :func:`seqnet.localize.stream.load_reference` and rebuilds the
map's describer (:func:`seqnet.localize.describing.map_describer`) when images can be described as the map was; each
session gets its own localiser from :meth:`LocalizeConfig.localizer <seqnet.localize.config.LocalizeConfig.localizer>`,
the one ``seqnet localize`` uses, over the shared reference.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.errors import ConfigError, SeqnetError
from ..core.log import logger
from ..core.provenance import image_size_of, sizes_clash, turned
from ..localize.config import LocalizeConfig
from ..localize.describing import map_describer
from ..localize.localizer import Estimate, Localizer
from ..localize.stream import load_reference
from ..methods.protocol import Reference
from .bodies import DESCRIPTOR_TYPE, BadBody, load_image, read_descriptor
from .errors import UNSUPPORTED, HttpError

if TYPE_CHECKING:
    from ..describe.describer import Describer

ROUTE_POINTS = 2000  # the live page draws at most this many reference positions


@dataclasses.dataclass
class Service:
    """The shared map and how frames reach a localiser.

    Attributes:
        conf: the localiser's settings; reference: the map; radius: its localisation radius; name: for /health.
        describer: the map's describer (images are described by it), or None; no_images: why images are refused.
    """

    conf: LocalizeConfig
    reference: Reference
    radius: float
    name: str
    describer: Describer | None = None
    check_image: Callable[[np.ndarray, str], None] | None = None  # the described image's provenance vs the map's
    no_images: str = ""

    @property
    def dim(self) -> int:
        """D of a frame's descriptor."""
        return int(self.reference.input_dim)

    @property
    def frames(self) -> int:
        """Frames of the map's reference traverse."""
        return len(self.reference.positions)

    def localizer(self) -> Localizer:
        """A new session's localiser (its own causal window) over the shared map."""
        return self.conf.localizer(self.reference, self.radius)

    def frame(self, body: bytes, kind: str) -> np.ndarray:
        """The descriptor ``[D]`` of a request body of content type ``kind``: as sent, or its image described.
        Every image is held to the map's image size (:func:`size_refusal`), whatever was sent before it."""
        if kind == DESCRIPTOR_TYPE:
            return read_descriptor(body, self.dim)
        if self.describer is None:
            raise HttpError(UNSUPPORTED, f"this server does not describe images ({self.no_images}); send "
                            f"descriptors ({DESCRIPTOR_TYPE})")
        images = load_image(self.describer, body, kind)
        seen = (int(images.shape[2]), int(images.shape[1]))
        prov = self.reference.provenance or {}
        refusal = size_refusal(prov, seen, self.conf.allow_mismatch)
        if refusal:
            raise BadBody(refusal)
        try:
            desc = self.describer(images)
            if desc.shape[1] != self.dim:
                raise BadBody(size_refusal(prov, seen, False, (int(desc.shape[1]), self.dim)) or "")
            self.check_image(desc, "the image as described here")
        except BadBody:
            raise
        except SeqnetError as e:
            raise BadBody(str(e)) from e
        return np.asarray(desc[0], dtype=np.float32)

    def answer(self, est: Estimate, spent_ms: float) -> dict[str, Any]:
        """The JSON answer of one frame (``spent_ms``: from its body, read, to its answer: describing, waiting for a
        worker thread, localising)."""
        ok = est.ref_index >= 0
        names, pos = self.reference.names, self.reference.positions
        return {"frame": int(est.frame), "estimate": int(est.ref_frame) if ok else None,
                "estimate_name": str(names[est.ref_frame]) if ok and names is not None else None,
                "score": _finite(est.score) if ok else None,
                "confidence": _finite(est.confidence) or 0.0,
                "position": [float(v) for v in pos[est.ref_frame][:2]] if ok and pos.ndim == 2 and pos.shape[1] >= 2
                else None,
                "latency_ms": round(float(spent_ms), 3), "full_window": bool(est.full_window)}

    def route(self) -> list[list[float]] | None:
        """Up to :data:`ROUTE_POINTS` reference positions ``[x, y]`` in route order (None without two axes)."""
        pos = np.asarray(self.reference.positions)
        if pos.ndim != 2 or pos.shape[1] < 2 or not len(pos):
            return None
        step = max(1, math.ceil(len(pos) / ROUTE_POINTS))
        keep = pos[::step, :2]
        return [[float(x), float(y)] for x, y in keep if math.isfinite(x) and math.isfinite(y)]

    def warm(self) -> float:
        """Step a throwaway localiser through one full window of zero frames, so that whatever the map builds on
        its first search is built before sessions share it; the milliseconds spent."""
        t0 = time.perf_counter()
        loc = self.localizer()
        for _ in range(loc.windows.longest):
            loc.step(np.zeros(self.dim, np.float32))
        return (time.perf_counter() - t0) * 1e3


def size_refusal(prov: dict, seen: tuple[int, int], allow: bool, dims: tuple[int, int] | None = None) -> str | None:
    """Why an image of ``seen`` ``(W, H)`` (as the map's describer crops and resizes it) is refused by a map of
    provenance ``prov``, phrased for an HTTP client; None when it is not. Before describing (``dims`` None) the
    sizes are held as ``seqnet localize`` holds them (:func:`seqnet.core.provenance.check_same`): refused when they
    differ and the descriptor is the pixel grid itself (``pixels``) or one side is portrait and the other landscape
    (unless ``allow``, ``--allow-mismatch``). ``dims``: ``(the image's D, the map's D)`` after describing, when
    they differ (always refused)."""
    want = image_size_of(prov)
    settings = prov.get("settings") if isinstance(prov.get("settings"), dict) else {}
    if dims is None and (want is None or allow or not sizes_clash(settings.get("method"), want, seen)):
        return None
    native = " (described at their own size)" if settings.get("size") == "native" else ""
    crop = settings.get("crop_bottom") if isinstance(settings.get("crop_bottom"), int) else 0
    cropped = f" after the map's crop of {crop} bottom rows" if crop else ""
    got = f"the image is {seen[0]}x{seen[1]}{cropped}"
    if want is None or (dims and seen == want):  # the map's image size unknown (or not the cause)
        return (f"{got} and gives D={dims[0] if dims else '?'}, this map's descriptors D={dims[1] if dims else '?'}"
                f"{native}: send frames of the size of the map's reference images")
    send = f"{want[0]}x{want[1] + crop}"
    if turned(want, seen):
        return (f"{got}, {'portrait' if seen[0] < seen[1] else 'landscape'}, and this map's images are "
                f"{want[0]}x{want[1]}{cropped}, {'portrait' if want[0] < want[1] else 'landscape'}{native}: a "
                f"turned camera? send frames as the map's were taken, {send}")
    return (f"{got} and this map's images are {want[0]}x{want[1]}{cropped}{native}: resize frames to {send} before "
            "sending")


def _finite(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def load_service(conf: LocalizeConfig, map_path: str | Path, models: Sequence[str | Path] = (),
                 shortlist_model: str | Path | None = None, rerank_model: str | Path | None = None,
                 describer: str | None = None) -> Service:
    """The map in ``map_path`` (an index map or a dataset directory, as ``seqnet localize --map``) with its
    models, its describer when one can be rebuilt (else images are refused, with the reason), warmed up."""
    from ..sequence.checkpoints import load_models

    loaded = load_models(models, shortlist_model, rerank_model, conf.seq_len)
    reference, radius, _ = load_reference(map_path, loaded, conf)
    service = Service(conf, reference, radius, Path(map_path).name)
    try:
        service.describer, service.check_image = map_describer(reference, conf.allow_mismatch, describer, map_path)
    except ConfigError as e:
        service.no_images = str(e).split(";")[0]
        logger.debug("serve: images are refused: %s", service.no_images)
    ms = service.warm()
    logger.debug("serve: map %s loaded and warmed up (%.1f ms)", map_path, ms)
    return service
