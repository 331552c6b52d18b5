"""HVPR's settings (K; ``hvpr-fused``'s K and λ) chosen on the dataset's val split when a map is built, or given to
``seqnet index build`` (``--top-k``, ``--fuse-top-k``, ``--fuse-weight``), stored in its ``map.json``
(``"selection"``), and used by ``seqnet localize --map``, ``seqnet serve`` and ``seqnet eval --index`` unless the
user gives them there.

The choice is :func:`seqnet.eval.select.choose_on_val`'s, the one ``seqnet eval`` and ``seqnet localize --dataset``
make (never on test), so the three routes use the same K on the same data. A map written before maps carried the
record, built from a dataset without a val split, or holding the val queries itself (``--split all``: a choice
``eval --index`` would score on the queries it was made on) keeps the defaults unless they are given at build.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..core.errors import ConfigError
from ..core.log import logger
from ..security.text import shown

if TYPE_CHECKING:
    from ..data.traverse import Dataset
    from ..methods.grammar import Method
    from ..sequence.model import SeqNet
    from .config import MapConfig

FLAGS = {"top_k": "--top-k", "fuse_top_k": "--fuse-top-k", "fuse_weight": "--fuse-weight"}
NAMES = {"top_k": "K", "fuse_top_k": "K", "fuse_weight": "λ"}


def settings_of(method: Method) -> tuple[str, ...]:
    """The settings of :data:`FLAGS` that the HVPR ``method`` uses: ``hvpr-fused``'s K and λ, else its K."""
    return ("fuse_top_k", "fuse_weight") if method.fused else ("top_k",)


def check_given(method: Method, given: Mapping[str, Any]) -> dict[str, Any]:
    """The settings given to ``seqnet index build`` (``{name: value or None}``), each one the map's method uses
    (refused otherwise, before any work, naming the flag it takes)."""
    given = {k: v for k, v in given.items() if v is not None}
    uses = settings_of(method)
    for k in given:
        if k not in FLAGS:
            raise ConfigError(f"unknown HVPR setting {k!r}; valid: {', '.join(FLAGS)}")
        if k not in uses:
            raise ConfigError(f"{FLAGS[k]} is not a setting of the map's method {method.name}; it takes "
                              f"{' / '.join(FLAGS[u] for u in uses)}")
    return given


def choose_for_map(conf: MapConfig, ds: Dataset, split: str, models: Mapping[str, SeqNet],
                   dataset: str | Path, given: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The ``"selection"`` record of a map of ``split`` of ``ds`` (the dataset directory ``dataset``) with the
    resolved ``conf``: the map's HVPR settings ``given`` to ``seqnet index build`` (``"given"``; checked by
    :func:`check_given` before any work), the others chosen on the val split
    (:func:`seqnet.eval.select.choose_on_val`), with the val R@1 of each choice; ``"not_chosen"``
    says why none was chosen (no val split, the map's split is val or holds val queries, no val query to score).
    Said in one line."""
    from ..eval.config import EvalConfig
    from ..eval.select import choose_on_val, holds_val_queries

    method, given = conf.method, dict(given or {})
    free = [k for k in settings_of(method) if k not in given]
    econf = EvalConfig(methods=(method.name,), seq_len=conf.seq_len, match_len=conf.match_len, window=conf.window,
                       device=conf.device, allow_mismatch=conf.allow_mismatch, **given)
    sel: dict[str, Any] = {}
    if free and split != "val" and holds_val_queries(ds, split):
        sel["not_chosen"] = (f"HVPR settings not chosen on the val split: the map's split {split!r} holds the val "
                             "queries, which eval --index on it would score with their own choice (the defaults "
                             f"kept: {econf.hvpr_settings(free)})")
    elif free:
        sel = dict((choose_on_val(ds, split, models, econf, free, dataset)[1] or {}).get("selection") or {})
        if not sel.get("hvpr") and not sel.get("not_chosen"):  # choose_on_val says nothing of the val split itself
            sel["not_chosen"] = "HVPR settings not chosen on a val split: the map is of the val split itself (the " \
                "defaults kept)"
    settings = {k: v for c in sel.get("hvpr", []) for k, v in c["settings"].items()}
    record = {"method": method.name, "split": "val", "settings": {**settings, **given}, **sel,
              **({"given": given} if given else {})}
    logger.info("%s", shown(build_line(record)))
    return record


def build_line(record: Mapping[str, Any]) -> str:
    """The one line ``seqnet index build`` says of the ``"selection"`` record."""
    chosen, given = record.get("hvpr") or [], record.get("given") or {}
    lines = [str(c.get("reason", "")) for c in chosen]
    if given:
        lines.append(f"{record.get('method')}: " + ", ".join(f"{NAMES[k]} {v:g}" for k, v in given.items())
                     + " as given (" + " / ".join(FLAGS[k] for k in given) + ")")
    if not lines:
        flags = " / ".join(FLAGS[k] for k in ("fuse_top_k", "fuse_weight")) \
            if str(record.get("method", "")).startswith("hvpr-fused") else FLAGS["top_k"]
        return (f"{record.get('not_chosen') or 'HVPR settings not chosen'}; localize --map, serve and eval --index "
                f"use them unless given {flags} (to store others in the map: seqnet index build {flags})")
    extra = [str(record[k]) for k in ("warning", "leakage", "not_chosen") if record.get(k)]
    return "; ".join([*lines, *extra]) + "; stored in the map: localize --map, serve and eval --index use it"


def stored(meta: Mapping[str, Any] | None, method: str) -> dict[str, Any]:
    """The settings stored in a map's ``map.json`` for ``method`` (``{"top_k": K}``, or ``hvpr-fused``'s
    ``{"fuse_top_k": K, "fuse_weight": λ}``); empty for a map without the record, or of another method."""
    rec = (meta or {}).get("selection")
    if not isinstance(rec, dict) or rec.get("method") != method or not isinstance(rec.get("settings"), dict):
        return {}
    return {k: v for k, v in rec["settings"].items() if k in FLAGS and isinstance(v, int | float)
            and not isinstance(v, bool)}


def settings_to_use(meta: Mapping[str, Any] | None, method: str,
                    given: Mapping[str, Any]) -> tuple[dict[str, Any], str | None]:
    """``(settings, line)``: the map's stored settings of ``method`` that the user did not give (``given``:
    ``{name: value or None}`` of :data:`FLAGS`; a value given wins) and one line saying which were used; ``({},
    None)`` for a map without the record (the defaults, as before maps carried it)."""
    have = stored(meta, method)
    rec = (meta or {}).get("selection") if isinstance((meta or {}).get("selection"), dict) else None
    if rec is None or rec.get("method") != method:
        return {}, None
    if not have:
        why = shown(str(rec.get("not_chosen") or "nothing chosen on val"))
        own = {k: v for k, v in given.items() if v is not None}
        if own:  # the flags given are used: not the defaults
            return {}, f"{method}: " + ", ".join(f"{FLAGS[k]} {v:g}" for k, v in own.items()) + \
                f" as given (the map stores none: {why})"
        return {}, f"{method}: the defaults ({why})"
    use = {k: v for k, v in have.items() if given.get(k) is None}
    over = {k: given[k] for k in have if given.get(k) is not None}
    built = rec.get("given") if isinstance(rec.get("given"), dict) else {}
    r1 = next((c.get("recall") for c in rec.get("hvpr") or [] if isinstance(c, dict)), None)
    at = f": val R@1 {r1:.3f}" if isinstance(r1, float) else ""
    why = {k: "given to seqnet index build" if k in built else f"chosen on the val split when it was built{at}"
           for k in have}
    parts = []
    for reason in dict.fromkeys(why[k] for k in use):
        parts.append(", ".join(f"{NAMES[k]} {v:g}" for k, v in use.items() if why[k] == reason)
                     + f", the map's ({reason})")
    if over:
        parts.append(", ".join(f"{FLAGS[k]} {v:g} as given (the map's {NAMES[k]} {have[k]:g}, "
                               f"{'given at build' if k in built else 'chosen on val'}, not used)"
                               for k, v in over.items()))
    return use, f"{method}: " + "; ".join(parts)
