"""Where descriptors come from, and refusing to compare descriptors that were made differently.

A *provenance* record says how a set of descriptors was made: its ``kind`` (``describe``,
``synthetic``, ``external`` ...), the ``settings`` that determine the values (method, backbone,
image size, crop, patch, PCA / NetVLAD settings, D ...), a hash of the images any state was fitted
on (PCA, NetVLAD clusters), and an ``id`` hashing all of it. Descriptor files, datasets, trained
models and runs carry it; reference and query descriptors, and a model and the descriptors it is
used on, must have the same id. NetVLAD at 160×120 against 640×320 gives R@1 0.19 instead of 0.87
with no other sign of trouble: a wrong number is worse than an error, so a mismatch is a
:class:`ProvenanceError` naming both settings (``--allow-mismatch`` for experts). Unknown
provenance (files from elsewhere) is accepted: only the dimension is checked, said as a warning when the other side's
provenance is known (once per file), else as a debug note.

A record made from images also holds ``image_size``: ``[W, H]`` of the images as the describer saw them (after
cropping and resizing; at native size, the images' own size). It is not part of the ``id`` (records made before it
keep theirs, and so match new ones), but two records that both have it must agree where it matters: the same
settings on images of another shape give descriptors of the same D that do not compare when they describe the pixel
grid (``pixels``), or when one side is portrait and the other landscape (a rotated camera); a pooled CNN descriptor of
another camera's resolution compares, as before.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from .errors import ConfigError
from .log import logger, warn_once

PROVENANCE_SUFFIX = ".provenance.json"
# in a .npy's sidecar: the descriptors it belongs to (size and sampled hash) and their names; the record of the
# output being replaced, while it is
BOUND_KEY, REPLACES_KEY = "written_with", "replaces"
MAX_SIDECAR = 1 << 30
IMAGE_SIZE_KEY = "image_size"  # [W, H] of the images described: checked beside the id, not hashed into it
# settings a describe record leaves out at their default (seqnet.describe.config: ids made before them unchanged)
OMITTED_DEFAULTS: dict[str, Any] = {"views": ["raw"]}


class ProvenanceError(ConfigError):
    """Descriptors (or a model and descriptors) that were made differently are used together."""


def _digest(obj: Any) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:16]


def fit_digest(fit_images: Iterable[str]) -> str:
    """The hash of the images fitted state was computed on, as a provenance record stores it (order-independent)."""
    return _digest(sorted(str(p) for p in fit_images))


def make(kind: str, settings: Mapping[str, Any], fit_images: Iterable[str] | None = None,
         dim: int | None = None, fit: str | None = None, image_size: tuple[int, int] | None = None) -> dict[str, Any]:
    """A provenance record (see the module docstring); ``fit_images`` are the names or paths of the
    images fitted state was computed on (hashed: :func:`fit_digest`), or ``fit`` that hash itself (state
    fitted by another run and reused), ``dim`` the descriptor size D, ``image_size`` ``(W, H)`` of the images
    described (recorded beside the id, not in it)."""
    settings = json.loads(json.dumps(dict(settings), default=str))
    fit = fit_digest(fit_images) if fit_images is not None else fit
    record = {"kind": kind, "settings": settings, "fit_images": fit, "dim": dim}
    size = {IMAGE_SIZE_KEY: [int(v) for v in image_size]} if image_size else {}
    return {**record, "id": _digest(record), **size}


def image_size_of(record: Mapping[str, Any] | None) -> tuple[int, int] | None:
    """``(W, H)`` of the images a record's descriptors were made from; None when it does not say (older records,
    descriptors from elsewhere) or says something malformed."""
    size = (record or {}).get(IMAGE_SIZE_KEY)
    if isinstance(size, list) and len(size) == 2 and all(isinstance(v, int) and v > 0 for v in size):
        return size[0], size[1]
    return None


def settings_of(record: Mapping[str, Any] | None) -> dict[str, Any]:
    """The settings of a provenance record, those a describe record (one naming its ``method``) leaves out at their
    default (:data:`OMITTED_DEFAULTS`: ``views`` ``["raw"]``) filled in; ``{}`` when it has none."""
    settings = (record or {}).get("settings")
    if not isinstance(settings, Mapping):
        return {}
    return {**(OMITTED_DEFAULTS if "method" in settings else {}), **settings}


def views_text(views: Any) -> str | None:
    """``views raw,equalize`` for a list of photometric views other than the default (``["raw"]``); None for the
    default, none given, or not a list (for messages: one spelling wherever views are said)."""
    if not isinstance(views, (list, tuple)) or not views or list(views) == OMITTED_DEFAULTS["views"]:
        return None
    return "views " + ",".join(map(str, views))


def described_text(record: Mapping[str, Any] | None) -> str:
    """How a record's descriptors were described, for a log line: ``pixels``, ``netvlad, views raw,equalize``
    (views only when not the default), then ``D=...`` when known; ``""`` when the record says neither."""
    settings, dim = settings_of(record), (record or {}).get("dim")
    views = views_text(settings.get("views"))
    parts = ([str(settings["method"])] if "method" in settings else []) + ([views] if views else [])
    return ", ".join(parts + ([f"D={dim}"] if isinstance(dim, int) else []))


def differences(a: Mapping[str, Any], b: Mapping[str, Any]) -> list[str]:
    """``key: value_a vs value_b`` for every setting (and the fit and D) that differs."""
    out = [f"kind: {a.get('kind')} vs {b.get('kind')}"] if a.get("kind") != b.get("kind") else []
    sa, sb = settings_of(a), settings_of(b)
    out += [f"{k}: {json.dumps(sa.get(k), default=str)} vs {json.dumps(sb.get(k), default=str)}"
            for k in sorted(set(sa) | set(sb), key=str) if sa.get(k) != sb.get(k)]
    if a.get("fit_images") != b.get("fit_images"):
        out.append("fitted state (PCA / NetVLAD clusters): fitted on different images")
    if a.get("dim") != b.get("dim"):
        out.append(f"D: {a.get('dim')} vs {b.get('dim')}")
    (wa, ha), (wb, hb) = image_size_of(a) or (0, 0), image_size_of(b) or (0, 0)
    if wa and wb and (wa, ha) != (wb, hb):
        out.append(f"images: {wa}x{ha} vs {wb}x{hb}")
    return out


def check_same(a: Mapping[str, Any] | None, b: Mapping[str, Any] | None, what_a: str, what_b: str,
               allow: bool = False) -> None:
    """Raise :class:`ProvenanceError` when both records are known and differ (unless ``allow``)."""
    if not a or not b:
        _say_unknown(what_a if not a else what_b, what_b if not a else what_a, known=bool(a or b))
        return
    if a.get("id") == b.get("id"):
        _check_sizes(a, b, what_a, what_b, allow)
        return
    diff = differences(a, b) or ["their provenance records differ"]
    if allow:
        logger.warning("%s and %s were made differently (%s); going on as asked (--allow-mismatch)",
                       what_a, what_b, "; ".join(diff))
        return
    raise ProvenanceError(f"{what_a} and {what_b} were made differently: {'; '.join(diff)}; "
                          f"{mismatch_hint(a, b, what_a, what_b)}")


def mismatch_hint(a: Mapping[str, Any], b: Mapping[str, Any], what_a: str, what_b: str) -> str:
    """The hint of a refused mismatch of two records: the ``--views`` to give when their views differ, else the same
    settings; ``--allow-mismatch`` only when both have the same D (descriptors of two sizes never compare: it
    cannot help then)."""
    va, vb = settings_of(a).get("views"), settings_of(b).get("views")
    default = OMITTED_DEFAULTS["views"]
    if va != vb and isinstance(va, list) and isinstance(vb, list) and default in (va, vb):
        plain, other, views = (what_a, what_b, vb) if va == default else (what_b, what_a, va)
        hint = (f"hint: make {plain} with --views {','.join(map(str, views))} as {other} were, or both without "
                "--views")
    elif va != vb:
        hint = "hint: make both with the same --views (the same views, in the same order)"
    else:
        hint = "hint: describe both with the same settings and fitted state (seqnet dataset from-images does)"
    da, db = a.get("dim"), b.get("dim")
    if isinstance(da, int) and isinstance(db, int) and da != db:
        return hint
    return f"{hint}, or pass --allow-mismatch if you know they are comparable"


def turned(sa: tuple[int, int], sb: tuple[int, int]) -> bool:
    """Whether of two ``(W, H)`` image sizes one is portrait and the other landscape (a rotated camera)."""
    return (sa[0] - sa[1]) * (sb[0] - sb[1]) < 0


def sizes_clash(method: Any, sa: tuple[int, int], sb: tuple[int, int]) -> bool:
    """Whether descriptors of ``method`` from images of sizes ``sa`` and ``sb`` do not compare: the sizes differ and
    the descriptor is the pixel grid itself (``pixels``) or one image is portrait and the other landscape (a pooled
    CNN descriptor of another camera's resolution compares)."""
    return tuple(sa) != tuple(sb) and (method == "pixels" or turned(sa, sb))


def _check_sizes(a: Mapping[str, Any], b: Mapping[str, Any], what_a: str, what_b: str, allow: bool) -> None:
    """Raise :class:`ProvenanceError` when two records of the same settings both record their images' size and
    the sizes differ (a warning with ``allow``)."""
    sa, sb = image_size_of(a), image_size_of(b)
    if sa is None or sb is None or not sizes_clash((a.get("settings") or {}).get("method"), sa, sb):
        return
    native = (a.get("settings") or {}).get("size") == "native"
    msg = (f"{what_a} were made from {sa[0]}x{sa[1]} images and {what_b} from {sb[0]}x{sb[1]} images"
           f"{' (native size)' if native else ''}: the same settings on images of another shape (rotated? another "
           "camera?) give descriptors that do not compare")
    if allow:
        logger.warning("%s; going on as asked (--allow-mismatch)", msg)
        return
    raise ProvenanceError(f"{msg}; hint: describe both at one size (--resize {sa[0]}x{sa[1]} where the command "
                          "has it, else `seqnet describe --resize` for the other side), or pass --allow-mismatch if "
                          "you know they are comparable")


def _say_unknown(unknown: str, other: str, known: bool) -> None:
    """Say that ``unknown``'s provenance is unknown: a warning (once per process and ``unknown``) when ``other``'s
    is known, since descriptors made otherwise (another describer, random vectors) then pass on their D alone; a
    debug note when neither is known (files all from elsewhere: there is nothing to hold them to)."""
    if not known:
        logger.debug("provenance of %s unknown: only the descriptor dimension is checked", unknown)
        return
    warn_once(("provenance unknown", unknown),
              "provenance of %s unknown: only the descriptor dimension is checked against %s, so descriptors made "
              "otherwise (another describer or its settings) would pass; hint: make them with `seqnet describe` and "
              "the same settings (it writes <stem>%s beside them, which is then checked)", unknown, other,
              PROVENANCE_SUFFIX)


def sidecar(path: str | Path) -> Path:
    """The provenance file written beside a ``.npy`` descriptor file: ``<stem>.provenance.json``."""
    p = Path(path)
    return p.with_name(p.stem + PROVENANCE_SUFFIX)
