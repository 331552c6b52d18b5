"""The benchmark's choices on the val range (never test): the descriptor before training, K and λ after.

The descriptor (:func:`choose_descriptor`): each candidate of ``conf.descriptors`` that can run here (a
CNN's backbone weights must ship with an installed package; nothing is downloaded) describes the val
places of both seasons (anything it fits, the NetVLAD clusters, fitted on at most :data:`PROXY_FIT` train
places of both seasons), and the model-free methods ``raw+seqmatch`` and ``single`` are evaluated on them;
the best ``raw+seqmatch`` val R@1 wins (ties: ``single``'s, then the candidate listed first, the cheapest).
It is a proxy: a descriptor that suits SeqMatch suits S_L and S_1 (on Nordland64's val every method
ranked NetVLAD above pixels above GMP, docs/experiments.md, Table S3).

K and λ (:func:`choose_hvpr`): :func:`seqnet.eval.select.select_hvpr` on the val range with the trained models.
"""

from __future__ import annotations

import importlib.util
import time
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...core.errors import ConfigError, DatasetError
from ...core.log import logger
from ...data.traverse import Dataset, Traverse
from ...describe import DescribeConfig, make_describer
from ...describe.lite import LITE_VARIANTS
from ...eval.evaluate import EvalConfig, evaluate
from ...eval.select import Choice, select_hvpr
from .config import Nordland64Config

if TYPE_CHECKING:
    from ...sequence.model import SeqNet

PROXY_METHODS = ("raw+seqmatch", "single")  # the proxy's score, then its tie-break
PROXY_FIT = 250  # train places (of each season) the proxy fits a candidate's state on, evenly spaced


def candidate_config(conf: Nordland64Config, name: str) -> DescribeConfig:
    """The describe settings of candidate ``name``: the benchmark's pixels, or a CNN method at ``conf.cnn_size``
    (the settings ``--descriptor NAME --cnn-size WxH`` gives)."""
    if name == "pixels":
        return conf.describe if conf.describe.method == "pixels" else DescribeConfig(method="pixels", patch=16,
                                                                                     size="native")
    return DescribeConfig(method=name, size=conf.cnn_size)


def runnable(dconf: DescribeConfig) -> str | None:
    """Why ``dconf`` cannot run here without downloading anything (None: it can)."""
    if dconf.method == "pixels":
        return None
    variant = LITE_VARIANTS.get(dconf.backbone)
    if variant is None:
        return f"its backbone {dconf.backbone} ships no weights"
    if importlib.util.find_spec(variant.module) is None:
        return f"the package {variant.package} (its {dconf.backbone} weights) is not installed"
    return None


def proxy_scores(data: Path, names: list[str], pos: np.ndarray, conf: Nordland64Config, offset: int,
                 dconf: DescribeConfig) -> dict[str, Any]:
    """Val R@1 of :data:`PROXY_METHODS` with descriptor ``dconf``: only the val places of ``names`` (place
    ``offset + i`` is ``names[i]``) are described, and a fitted state is fitted on train places."""
    from .data import SEASONS

    t0 = time.perf_counter()
    (a, b), (c, d) = conf.train_range, conf.val_range
    train = names[a - offset: b - offset]
    train = [train[i] for i in np.unique(np.linspace(0, len(train) - 1, min(PROXY_FIT, len(train))).astype(int))]
    fit = [data / s / n for s in SEASONS for n in train]
    describer = make_describer(dconf.replace(fit=fit) if dconf.needs_fit else dconf, fit)
    val, vpos = names[c - offset: d - offset], pos[c - offset: d - offset]
    desc = {}
    for season in SEASONS:
        desc[season], got = describer.describe([data / season / n for n in val], val)
        if len(got) != len(val):
            raise DatasetError(f"{len(val) - len(got)} {season} val images could not be read")
    ds = Dataset(Traverse(desc[SEASONS[0]], vpos, name=SEASONS[0]), Traverse(desc[SEASONS[1]], vpos, name=SEASONS[1]),
                 radius=conf.radius, position_unit="frames", name="nordland64 val")
    ev = evaluate(ds, EvalConfig(methods=PROXY_METHODS, seq_len=conf.seq_len, ks=(1,), device=conf.device,
                                 recall_denominator=conf.recall_denominator, common_queries=True))
    out = {m: round(float(ev.results["methods"][m]["recall@1"]), 6) for m in PROXY_METHODS}
    return {**out, "queries": int(ev.results["methods"][PROXY_METHODS[0]]["queries"]),
            "dim": int(desc[SEASONS[0]].shape[1]), "seconds": round(time.perf_counter() - t0, 2)}


def descriptor_on_val(conf: Nordland64Config, data: str | Path) -> tuple[Nordland64Config, dict[str, Any] | None]:
    """``conf`` with its descriptor chosen on val when ``conf.select`` asks for it and there is a choice
    (:func:`choose_descriptor`), and the record of the choice (None: no choice made)."""
    if "descriptor" not in conf.select or len(conf.descriptors) < 2:
        return conf, None
    from .data import list_places, split_ranges

    names, pos = list_places(data, conf.names_file)
    lo, _ = split_ranges(conf, len(names))
    return choose_descriptor(data, names[lo:], pos[lo:], conf, lo)


def choose_descriptor(data: str | Path, names: list[str], pos: np.ndarray, conf: Nordland64Config,
                      offset: int = 0) -> tuple[Nordland64Config, dict[str, Any]]:
    """``conf`` with the descriptor the val proxy prefers among ``conf.descriptors`` (see the module
    docstring), and the record of the choice (``{"chosen", "scores", "skipped", "reason"}``)."""
    scores, skipped = {}, {}
    for name in conf.descriptors:
        dconf = candidate_config(conf, name)
        why = runnable(dconf)
        if why is not None:
            skipped[name] = why
            logger.info("descriptor %s left out of the choice: %s", name, why)
            continue
        logger.info("val proxy: describing the val places with %s", name)
        scores[name] = proxy_scores(Path(data), names, pos, conf, offset, dconf)
    if not scores:
        raise ConfigError(f"no descriptor candidate can run here ({'; '.join(f'{k}: {v}' for k, v in skipped.items())})"
                          "; hint: --descriptor pixels")
    best = max(scores, key=lambda n: (*(scores[n][m] for m in PROXY_METHODS), -list(scores).index(n)))
    c, d = conf.val_range
    others = ", ".join(f"{n} {s[PROXY_METHODS[0]]:.3f}" for n, s in scores.items() if n != best)
    reason = (f"descriptor {best} chosen on val places {c}:{d} ({scores[best]['queries']} queries) before training: "
              f"model-free {PROXY_METHODS[0]} R@1 {scores[best][PROXY_METHODS[0]]:.3f} "
              f"(single {scores[best]['single']:.3f})" + (f" against {others}" if others else "")
              + (f"; not tried: {', '.join(skipped)}" if skipped else ""))
    record = {"chosen": best, "describe": candidate_config(conf, best).to_dict(), "scores": scores,
              "skipped": skipped, "reason": reason}
    logger.info("%s", reason)
    return conf.replace(describe=candidate_config(conf, best)), record


def choose_hvpr(val: Dataset, models: Mapping[str, SeqNet], conf: Nordland64Config,
                econf: EvalConfig) -> tuple[Nordland64Config, EvalConfig, list[Choice]]:
    """``conf`` and its evaluation settings ``econf`` with the HVPR settings of ``conf.select`` chosen on
    ``val`` (the val range, as evaluated), and the choices."""
    econf, choices = select_hvpr(val, models, econf, [s for s in conf.select if s != "descriptor"],
                                 f"val places {conf.val_range[0]}:{conf.val_range[1]}")
    for ch in choices:
        logger.debug("%s", ch.reason)
    conf = conf.replace(top_k=econf.top_k, fuse_top_k=econf.fuse_top_k or conf.fuse_top_k,
                        fuse_weight=econf.fuse_weight)
    return conf, econf, choices
