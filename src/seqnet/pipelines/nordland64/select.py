"""The benchmark's choices on the val range (never test): the descriptor before training, K and λ after.

The descriptor (:func:`choose_descriptor`): :mod:`seqnet.pipelines.descriptor_choice` over the candidates of
``conf.descriptors``, each describing only the val places of both seasons (a fitted state, the NetVLAD
clusters, fitted on train places of both seasons).

K and λ (:func:`choose_hvpr`): :func:`seqnet.eval.select.select_hvpr` on the val range with the trained models.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...core.errors import DatasetError, OutputError
from ...core.log import logger
from ...data.traverse import Dataset, Traverse
from ...describe import DescribeConfig, make_describer
from ...eval.config import EvalConfig
from ...eval.select import Choice, select_hvpr
from ...security.files import write_json_atomic
from ...security.jsonfile import read_json
from ...security.text import shown
from .. import descriptor_choice as choice
from ..descriptor_choice import candidate_describe, evenly, runnable
from . import cache
from .config import Nordland64Config

MAX_CHOICE = 1 << 20  # bytes of a cached choice record

if TYPE_CHECKING:
    from ...sequence.model import SeqNet

def candidate_config(conf: Nordland64Config, name: str) -> DescribeConfig:
    """The describe settings of candidate ``name``: the benchmark's pixels, or a CNN method at ``conf.cnn_size``
    (the settings ``--descriptor NAME --cnn-size WxH`` gives; ``METHOD+VIEW``: also ``--views raw,VIEW``,
    :func:`~seqnet.pipelines.descriptor_choice.candidate_describe`)."""
    if name == "pixels":
        return conf.describe if conf.describe.method == "pixels" else DescribeConfig(method="pixels", patch=16,
                                                                                     size="native")
    return candidate_describe(DescribeConfig(size=conf.cnn_size), name)


def proxy_scores(data: Path, names: list[str], pos: np.ndarray, conf: Nordland64Config, offset: int,
                 dconf: DescribeConfig) -> dict[str, Any]:
    """Val R@1 of :data:`~seqnet.pipelines.descriptor_choice.PROXY_METHODS` with descriptor ``dconf``: only the
    val places of ``names`` (place ``offset + i`` is ``names[i]``) are described, and a fitted state is fitted
    on train places."""
    from .data import SEASONS

    t0 = time.perf_counter()
    (a, b), (c, d) = conf.train_range, conf.val_range
    fit = [data / s / n for s in SEASONS for n in evenly(names[a - offset: b - offset])]
    describer = make_describer(dconf.merge(fit=fit) if dconf.needs_fit else dconf, fit)
    val, vpos = names[c - offset: d - offset], pos[c - offset: d - offset]
    desc = {}
    for season in SEASONS:
        desc[season], got = describer.describe([data / season / n for n in val], val)
        if len(got) != len(val):
            raise DatasetError(f"{len(val) - len(got)} {season} val images could not be read")
    ds = Dataset(Traverse(desc[SEASONS[0]], vpos, name=SEASONS[0]), Traverse(desc[SEASONS[1]], vpos, name=SEASONS[1]),
                 radius=conf.radius, position_unit="frames", name="nordland64 val")
    return {**choice.proxy_scores(ds, conf.seq_len, conf.device, conf.recall_denominator, t0),
            "fit_images": len(fit) if dconf.needs_fit else 0}


def descriptor_on_val(conf: Nordland64Config, data: str | Path, out: Path | None = None,
                      overwrite: bool = False) -> tuple[Nordland64Config, dict[str, Any] | None]:
    """``conf`` with its descriptor chosen on val when ``conf.select`` asks for it and there is a choice
    (:func:`choose_descriptor`), and the record of the choice (None: no choice made). With ``out`` (the
    benchmark's folder, locked by the caller) the choice is a cache unit (:mod:`.cache`): a later run with the
    same candidates, ranges and data reuses it (``"cached": true`` in the record) instead of describing again."""
    if "descriptor" not in conf.select or len(conf.descriptors) < 2:
        return conf, None
    from .data import list_places, split_ranges

    names, pos = list_places(data, conf.names_file)
    lo, splits = split_ranges(conf, len(names))
    hi = lo + max(r["query"][1] for r in splits.values())  # places after every range are never read
    key = choice_key(conf, Path(data), names[lo:hi])
    if out is not None and cache.unit(out, "choice", key) is not None:
        record = read_json(out / cache.CHOICE[0], "cached descriptor choice", OutputError, MAX_CHOICE)
        chosen = record.get("chosen") if isinstance(record, dict) else None
        if chosen in conf.descriptors and record.get("describe") == candidate_config(conf, chosen).to_dict() \
                and isinstance(record.get("reason"), str) and runnable(candidate_config(conf, chosen)) is None:
            logger.info("descriptor choice reused from %s: %s", shown(out / cache.CHOICE[0]), record["reason"])
            reason = f"{record['reason']} (an earlier run's choice in this folder, reused)"
            return conf.merge(describe=candidate_config(conf, chosen)), {**record, "reason": reason, "cached": True}
    conf, record = choose_descriptor(data, names[lo:hi], pos[lo:hi], conf, lo)
    if out is not None:
        cache.open_unit(out, "choice", cache.CHOICE, overwrite)  # its key removed first
        write_json_atomic(out / cache.CHOICE[0], record)
        cache.seal(out, "choice", key, list(cache.CHOICE))
    return conf, record


def choice_key(conf: Nordland64Config, data: Path, names: list[str]) -> str:
    """The key of a cached descriptor choice: everything the proxy reads (candidates, ranges, L, radius,
    denominator, device) and the data folder with its places in use."""
    blob = json.dumps({"candidates": {n: candidate_config(conf, n).to_dict() for n in conf.descriptors},
                       "ranges": [conf.train_range, conf.val_range], "seq_len": conf.seq_len, "radius": conf.radius,
                       "denominator": conf.recall_denominator, "device": conf.device, "source": str(data.resolve()),
                       "names": names}, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def choose_descriptor(data: str | Path, names: list[str], pos: np.ndarray, conf: Nordland64Config,
                      offset: int = 0) -> tuple[Nordland64Config, dict[str, Any]]:
    """``conf`` with the descriptor the val proxy prefers among ``conf.descriptors`` (see the module
    docstring), and the record of the choice (``{"chosen", "scores", "skipped", "reason"}``)."""
    from .data import SEASONS

    (a, b), (c, d) = conf.train_range, conf.val_range
    candidates = {name: candidate_config(conf, name) for name in conf.descriptors}
    final = len(SEASONS) * (b - a)  # the final descriptors' state: fitted on every train place of both seasons
    dconf, record = choice.choose_on_val(candidates, lambda dc: proxy_scores(Path(data), names, pos, conf, offset, dc),
                                         f"val places {c}:{d}", lambda dc: final if dc.needs_fit else 0)
    return conf.merge(describe=dconf), record


def choose_hvpr(val: Dataset, models: Mapping[str, SeqNet], conf: Nordland64Config,
                econf: EvalConfig) -> tuple[Nordland64Config, EvalConfig, list[Choice]]:
    """``conf`` and its evaluation settings ``econf`` with the HVPR settings of ``conf.select`` chosen on
    ``val`` (the val range, as evaluated), and the choices."""
    econf, choices = select_hvpr(val, models, econf, [s for s in conf.select if s != "descriptor"],
                                 f"val places {conf.val_range[0]}:{conf.val_range[1]}")
    for ch in choices:
        logger.debug("%s", ch.reason)
    conf = conf.merge(method_top_k=econf.method_top_k, method_fuse_weight=econf.method_fuse_weight)
    return conf, econf, choices
