"""Choosing the single-image descriptor on a val split, before training (never on test).

Each candidate that can run here (:func:`runnable`: a CNN's backbone weights must ship with an installed
package; nothing is downloaded) describes the val images of both traverses (anything it fits, such as the
NetVLAD clusters, fitted on at most :data:`PROXY_FIT` images of its fitting set, evenly spaced), and the
model-free methods :data:`PROXY_METHODS` are evaluated on them: the best ``raw+seqmatch`` val R@1 wins (ties:
``single``'s, then the candidate listed first, the cheapest). It is a proxy: a descriptor that suits SeqMatch
suits S_L and S_1 (on Nordland64's val every method ranked NetVLAD above pixels above GMP, docs/experiments.md,
Table S3).

Used by the Nordland64 benchmark (:mod:`seqnet.pipelines.nordland64.select`, without ``--descriptor``) and by
own data (:mod:`seqnet.pipelines.from_images`, ``seqnet dataset from-images`` without ``--method``).
"""

from __future__ import annotations

import importlib.util
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any, TypeVar

from ..core.errors import ConfigError
from ..core.log import logger
from ..core.provenance import views_text
from ..core.tensors import spread
from ..data.traverse import Dataset
from ..describe import DescribeConfig
from ..describe.lite import LITE_VARIANTS
from ..describe.views import DEFAULT_VIEWS, RAW
from ..eval.config import EvalConfig
from ..eval.score import score
from ..metrics.recall import VAL_MIN

PROXY_METHODS = ("raw+seqmatch", "single")  # the proxy's score, then its tie-break
PROXY_FIT = 250  # images (of each fitting set) a candidate's state is fitted on for the proxy, evenly spaced
# the default candidates, cheapest first; METHOD+VIEW: the method's descriptors of the raw and of that view of each
# image, concatenated (seqnet.describe.views: netvlad+equalize also describes the histogram-equalised images)
CANDIDATES = ("pixels", "netvlad", "netvlad+equalize", "gem", "gmp")

T = TypeVar("T")


def candidate_describe(base: DescribeConfig, name: str) -> DescribeConfig:
    """``base`` as candidate ``name`` describes: ``METHOD`` (its own view of the images), or ``METHOD+VIEW...``
    (the raw images and each named view, :mod:`seqnet.describe.views`)."""
    method, *views = name.split("+")
    return base.merge(method=method, views=(RAW, *views) if views else DEFAULT_VIEWS)


def candidate_name(dconf: DescribeConfig) -> str:
    """The candidate name of ``dconf`` (the inverse of :func:`candidate_describe`): ``netvlad``, or
    ``netvlad+equalize`` for views ``raw,equalize``; views not led by ``raw``: the method alone (its views said
    beside it where they matter: :func:`descriptor_text`)."""
    views = dconf.views
    return dconf.method + "".join(f"+{v}" for v in views[1:]) if views[0] == RAW else dconf.method


def descriptor_text(dconf: DescribeConfig, dim: int | None = None) -> str:
    """``dconf`` for a headline, in Markdown: the candidate name in backticks, then the views (when not the
    default) and D: ``netvlad+equalize`` (views raw,equalize, D=14336)."""
    views = views_text(list(dconf.views))
    extra = ([views] if views else []) + ([] if dim is None else [f"D={dim}"])
    return f"`{candidate_name(dconf)}`" + (f" ({', '.join(extra)})" if extra else "")


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


def evenly(items: Sequence[T], n: int = PROXY_FIT) -> list[T]:
    """At most ``n`` of ``items``, evenly spaced (the first and the last kept)."""
    return [items[i] for i in spread(len(items), n)]


def proxy_scores(val: Dataset, seq_len: int, device: str = "auto", recall_denominator: str = "positives",
                 t0: float | None = None) -> dict[str, Any]:
    """Val R@1 of :data:`PROXY_METHODS` on ``val`` (described with one candidate), the queries counted, the
    descriptor's D and the seconds since ``t0``."""
    t0 = time.perf_counter() if t0 is None else t0
    ev = score(val, EvalConfig(methods=PROXY_METHODS, seq_len=seq_len, ks=(1,), device=device,
                                  recall_denominator=recall_denominator, common_queries=True))
    out = {m: round(float(ev.results["methods"][m]["recall@1"]), 6) for m in PROXY_METHODS}
    return {**out, "queries": int(ev.results["methods"][PROXY_METHODS[0]]["queries"]), "dim": int(val.query.dim),
            "seconds": round(time.perf_counter() - t0, 2)}


def choose_on_val(candidates: Mapping[str, DescribeConfig], score: Callable[[DescribeConfig], dict[str, Any]],
                  where: str, final_fit: Callable[[DescribeConfig], int] | None = None, note: str = ""
                  ) -> tuple[DescribeConfig, dict[str, Any]]:
    """The candidate (``{name: settings}``) whose ``score(settings)`` (:func:`proxy_scores` of the val split it
    describes, with ``"fit_images"``: how many images its state was fitted on) is best, and the record of the choice
    (``{"chosen", "describe", "scores", "skipped", "reason"}``); ``where`` names the val split in the reason.
    Candidates that cannot run are skipped (said). ``final_fit(settings)``: how many images the final descriptors'
    state is fitted on; when the chosen one's differs from the proxy's, the reason says that its figures are the
    proxy's (an evaluation of the final descriptors on the same split gives others). ``note``: appended to the
    reason (e.g. that its figures come before a ``--pca``)."""
    scores, skipped = {}, {}
    for name, dconf in candidates.items():
        why = runnable(dconf)
        if why is not None:
            skipped[name] = why
            logger.info("descriptor %s left out of the choice: %s", name, why)
            continue
        logger.info("val proxy: describing the val images with %s", name)
        scores[name] = score(dconf)
    if not scores:
        raise ConfigError(f"no descriptor candidate can run here ({'; '.join(f'{k}: {v}' for k, v in skipped.items())})"
                          "; hint: choose one (pixels needs nothing)")
    order = list(scores)
    best = max(scores, key=lambda n: (*(scores[n][m] for m in PROXY_METHODS), -order.index(n)))
    others = ", ".join(f"{n} {s[PROXY_METHODS[0]]:.3f}" for n, s in scores.items() if n != best)
    reason = (f"descriptor {best} chosen on {where} ({scores[best]['queries']} queries) before training, by the "
              f"val proxy's model-free {PROXY_METHODS[0]} R@1 {scores[best][PROXY_METHODS[0]]:.3f} "
              f"(single {scores[best]['single']:.3f})" + (f" against {others}" if others else "")
              + proxy_fit_note(scores[best].get("fit_images"), final_fit(candidates[best]) if final_fit else None)
              + (f"; not tried: {', '.join(skipped)}" if skipped else "") + note)
    logger.info("%s", reason)
    record = {"chosen": best, "describe": candidates[best].to_dict(), "scores": scores, "skipped": skipped,
              "reason": reason}
    n = int(scores[best]["queries"])
    if n < VAL_MIN and len(scores) > 1:
        record["warning"] = (f"the descriptor was chosen on {n} val queries (one query moves R@1 by "
                             f"{1 / max(n, 1):.2f}): the choice is mostly chance; about {VAL_MIN} or more are needed "
                             "(a larger --split val=A:B, or --method to choose yourself)")
        logger.warning("%s", record["warning"])
    return candidates[best], record


def proxy_fit_note(proxy: int | None, final: int | None) -> str:
    """The reason's note when the proxy fitted the chosen descriptor's state (NetVLAD clusters, PCA) on ``proxy``
    images and the final descriptors fit it on ``final`` others: the proxy's R@1 are not the final descriptors'
    (empty when either fits nothing or both fit on as many images)."""
    if not proxy or not final or proxy == final:
        return ""
    return (f" (the proxy's figures: its fitted state on {proxy} images, the final descriptors' on {final}, so their "
            "val R@1 differ)")
