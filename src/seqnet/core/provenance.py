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


class ProvenanceError(ConfigError):
    """Descriptors (or a model and descriptors) that were made differently are used together."""


def _digest(obj: Any) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:16]


def fit_digest(fit_images: Iterable[str]) -> str:
    """The hash of the images fitted state was computed on, as a provenance record stores it (order-independent)."""
    return _digest(sorted(str(p) for p in fit_images))


def make(kind: str, settings: Mapping[str, Any], fit_images: Iterable[str] | None = None,
         dim: int | None = None, fit: str | None = None) -> dict[str, Any]:
    """A provenance record (see the module docstring); ``fit_images`` are the names or paths of the
    images fitted state was computed on (hashed: :func:`fit_digest`), or ``fit`` that hash itself (state
    fitted by another run and reused), ``dim`` the descriptor size D."""
    settings = json.loads(json.dumps(dict(settings), default=str))
    fit = fit_digest(fit_images) if fit_images is not None else fit
    record = {"kind": kind, "settings": settings, "fit_images": fit, "dim": dim}
    return {**record, "id": _digest(record)}


def differences(a: Mapping[str, Any], b: Mapping[str, Any]) -> list[str]:
    """``key: value_a vs value_b`` for every setting (and the fit and D) that differs."""
    out = [f"kind: {a.get('kind')} vs {b.get('kind')}"] if a.get("kind") != b.get("kind") else []
    sa, sb = (s if isinstance(s, Mapping) else {} for s in (a.get("settings"), b.get("settings")))
    out += [f"{k}: {json.dumps(sa.get(k), default=str)} vs {json.dumps(sb.get(k), default=str)}"
            for k in sorted(set(sa) | set(sb), key=str) if sa.get(k) != sb.get(k)]
    if a.get("fit_images") != b.get("fit_images"):
        out.append("fitted state (PCA / NetVLAD clusters): fitted on different images")
    if a.get("dim") != b.get("dim"):
        out.append(f"D: {a.get('dim')} vs {b.get('dim')}")
    return out


def check_same(a: Mapping[str, Any] | None, b: Mapping[str, Any] | None, what_a: str, what_b: str,
               allow: bool = False) -> None:
    """Raise :class:`ProvenanceError` when both records are known and differ (unless ``allow``)."""
    if not a or not b:
        _say_unknown(what_a if not a else what_b, what_b if not a else what_a, known=bool(a or b))
        return
    if a.get("id") == b.get("id"):
        return
    diff = differences(a, b) or ["their provenance records differ"]
    if allow:
        logger.warning("%s and %s were made differently (%s); going on as asked (--allow-mismatch)",
                       what_a, what_b, "; ".join(diff))
        return
    raise ProvenanceError(f"{what_a} and {what_b} were made differently: {'; '.join(diff)}; hint: describe both "
                          "with the same settings and fitted state (seqnet dataset from-images does), or pass "
                          "--allow-mismatch if you know they are comparable")


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
