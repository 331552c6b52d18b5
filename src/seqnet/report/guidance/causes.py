"""The likely causes of a learned method below its model-free counterpart (:func:`likely_causes`), read from what an
evaluation's results record: the gap in queries, the shortlist's recall, the models' D and L, the evaluated queries,
the training queries each checkpoint records (:func:`model_entries`)."""

from __future__ import annotations

import functools
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ...core.log import counted
from ...methods.checks import role_label
from ...methods.grammar import parse_method

CHANCE_QUERIES = 5  # the largest gap in queries a sign test at 0.05 cannot tell from chance (2 * 0.5**6 < 0.05)


def likely_causes(name: str, results: Mapping[str, Any], gap: tuple[float, float] | None = None, *,
                  explained: bool = False, k: int = 1) -> tuple[str, ...]:
    """The usual causes of a learned method ``name`` losing to a model-free one, most specific first: a gap
    within chance (``gap``: the two R@1), a model-free shortlist, a model on descriptors of D > 4096 (no PCA),
    a model trained at another L than evaluated, few evaluated queries; then, when nothing specific is seen,
    the causes the results cannot show (training data, val split); not those when ``explained`` (the gap is a
    cause said beside these: a PCA's cost)."""
    cfg = results.get("config", {})
    methods = results.get("methods", {})
    entry = methods.get(name, {})
    models = (entry.get("method") or {}).get("models") or cfg.get("models") or {}
    out = []
    queries = entry.get("queries")
    apart = round((gap[1] - gap[0]) * queries) if gap is not None and isinstance(queries, int) else None
    chance = apart is not None and within_chance(apart)
    if chance:
        out.append(f"possibly chance: {apart} of {queries} queries apart (a sign test cannot tell fewer than "
                   f"{CHANCE_QUERIES + 1} apart from chance)")
    m = parse_method(name)
    capped = shortlist_capped(name, entry, gap[1] if gap is not None else None)
    if capped:
        out.append(capped)
    capped = bool(capped) and "which caps its R@1" in capped  # the whole loss: no training cause beside it
    free_shortlist = free_shortlist_cause(name, entry, methods, cfg)
    if free_shortlist:
        out.append(free_shortlist)
    out += elsewhere(models)
    narrow = narrow_layers(models)
    out += [narrow] if narrow else []
    dims = sorted({int(v["in_dims"]) for v in models.values() if isinstance(v, Mapping) and "in_dims" in v})
    from ...describe.pca import PAPER_PCA_DIM  # here: the describe package (its describers, h5py) loads with it

    folded = (cfg.get("benchmark") or {}).get("pca_dims") if isinstance(cfg.get("benchmark"), Mapping) else None
    if dims and dims[-1] > PAPER_PCA_DIM and not folded:  # a PCA folded into the models reads D raw dims too
        out.append(f"D = {dims[-1]} without PCA (the paper reduces to {PAPER_PCA_DIM}; seqnet train --pca D, or seqnet "
                   "dataset from-images --pca D, fitted on the train split)")
    trained = models.get("seqnet", {}).get("seq_len") if isinstance(models.get("seqnet"), Mapping) else None
    evaluated = (entry.get("method") or {}).get("seq_len") or cfg.get("seq_len")
    if "seqnet" in m.models() and trained and evaluated and int(trained) != int(evaluated):
        out.append(f"S_L trained on windows of L={trained} but evaluated at L={evaluated} (--seq-len {trained})")
    if isinstance(queries, int) and 0 < queries < 50:
        out.append(f"only {queries} evaluated queries (one query is {1 / queries:.2f} of R@{k})")
    if (early := barely_trained(models, narrow=bool(narrow))) and not chance:
        out.append(early)
    if not (chance or capped or free_shortlist or explained):  # the other causes (D, L, few queries): said beside
        out.append(f"too little or too different training data for the model's D x out x w weights{learnt(models)}, "
                   "or a val split too small to choose the epoch (the training log of seqnet train says both)")
    return tuple(out)


def elsewhere(models: Mapping[str, Any]) -> list[str]:
    """A line for each model whose checkpoint was trained on another dataset than the one evaluated
    (``trained_on_dataset`` of its entry: :func:`seqnet.eval.score.trained_elsewhere`)."""
    return [f"{role_label(role)} was trained on another dataset ({v['trained_on_dataset']}): a model learns the "
            "descriptors and places it trained on, and another describer's descriptors of the same D fit it in shape "
            "only (hint: train on this dataset's train split: seqnet train --dataset THIS)"
            for role, v in sorted(models.items()) if isinstance(v, Mapping)
            and isinstance(v.get("trained_on_dataset"), str)]


def free_shortlist_cause(name: str, entry: Mapping[str, Any], methods: Mapping[str, Any],
                         cfg: Mapping[str, Any]) -> str | None:
    """An HVPR on a model-free shortlist: it re-ranks only what that shortlist ranks, with the learned HVPRs that did
    better here (or that were not evaluated); None for any other method."""
    m = parse_method(name)
    if not (m.kind == "hvpr" and m.shortlist and not parse_method(m.shortlist).models()):
        return None
    top = (entry.get("method") or {}).get("top_k") or cfg.get("top_k")
    r1 = entry.get("recall@1", 0.0)
    better = [b for b in ("hvpr", "hvpr-fused") if isinstance((methods.get(b) or {}).get("recall@1"), float)
              and methods[b]["recall@1"] > r1]
    absent = [b for b in ("hvpr", "hvpr-fused") if b not in methods]
    hint = f" (better here: {', '.join(better)})" if better else \
        f" (a learned shortlist: {', '.join(absent)})" if absent else ""
    return (f"its shortlist is the model-free {m.shortlist}: it re-ranks only the places {m.shortlist} ranks in its "
            f"top {top or 'K'}{hint}")


def learnt(models: Mapping[str, Any]) -> str:
    """`` (S_1 learnt from 12 training queries)``: the training queries each model's checkpoint records
    (``training_queries`` of :func:`model_entries`); "" when none does."""
    said = [f"{role_label(role)} learnt from {counted(n, 'training query', 'training queries')}"
            for role, v in sorted(models.items(), key=lambda kv: kv[0] != "seqnet") if isinstance(v, Mapping)
            and type(n := v.get("training_queries")) is int and n > 0]
    return f" ({', '.join(said)})" if said else ""


def model_entries(models: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """What ``results.json`` records of each model by role (:func:`likely_causes` reads it): its architecture
    (``in_dims``, ``out_dims``, ``seq_len``, ``w``) and, when its checkpoint records them, the number of its
    training queries (``training_queries``: those it trained on; for older checkpoints its train range's length)."""
    out = {}
    for role, model in models.items():
        t = getattr(model, "trained_on", None)
        rng = t.get("train_queries") if isinstance(t, Mapping) else None
        ok = isinstance(rng, list | tuple) and len(rng) == 2 and all(type(v) is int for v in rng) and rng[1] > rng[0]
        record = training_record(str(t["checkpoint"])) if isinstance(t, Mapping) and t.get("checkpoint") else None
        n = t.get("trained_queries") if isinstance(t, Mapping) else None
        n = n if type(n) is int and n >= 0 else rng[1] - rng[0] if ok else None
        out[role] = {**model.config(), **({"training_queries": n} if n is not None else {}),
                     **({"training": record} if record else {})}
    return out


def training_record(path: str) -> dict[str, Any] | None:
    """What the checkpoint ``path`` and the ``last.pt`` beside it (same run) record of its training:
    ``{"epoch": the chosen epoch, "epochs": planned, "last_epoch": run, "loss": {epoch: training loss}}`` (the
    losses and the last epoch only with that ``last.pt``); None when unreadable (tensors mapped, not read)."""
    try:
        stat = os.stat(path)
        return _record(path, stat.st_mtime_ns)
    except OSError:
        return None


@functools.lru_cache(maxsize=32)
def _record(path: str, mtime: int) -> dict[str, Any] | None:
    from ...core.errors import SeqnetError
    from ...sequence.checkpoints import read_checkpoint

    try:
        best = read_checkpoint(path, mapped=True)
        last_path = Path(path).with_name("last.pt")
        last = best if Path(path).name == "last.pt" or not last_path.is_file() else \
            read_checkpoint(last_path, mapped=True)
    except (SeqnetError, OSError):
        return None
    epoch, epochs = best.get("epoch"), (best.get("config") or {}).get("epochs")
    if type(epoch) is not int or type(epochs) is not int:
        return None
    same = last.get("dataset_path") == best.get("dataset_path") and last.get("best_epoch") == best.get("best_epoch")
    history = (last.get("train_state") or {}).get("history") if same else None
    loss = {int(h["epoch"]): float(h["loss"]) for h in history or [] if isinstance(h, Mapping)
            and type(h.get("epoch")) is int and isinstance(h.get("loss"), float)}
    conf = best.get("config") or {}
    how = {k: conf[k] for k in ("optimizer", "lr") if isinstance(conf.get(k), str | float)}
    return {"epoch": epoch, "epochs": epochs, **how, **({"last_epoch": max(loss), "loss": loss} if loss else {})}


NARROW_SHARE = 4  # out_dims at most in_dims / this (or below NARROW_DIMS): a layer that narrow loses the descriptor
NARROW_DIMS = 32


def narrow_layers(models: Mapping[str, Any]) -> str | None:
    """The models whose layer maps D dimensions to far fewer (``out_dims`` at most ``in_dims`` / :data:`NARROW_SHARE`
    or below :data:`NARROW_DIMS`: ``--out-dims 16`` / ``64`` on 256-D descriptors scored s1 R@1 0.050 / 0.217
    against single 0.433, 0.467 without it), said with the fix; None when none is."""
    said = [f"{role_label(role)} maps {v['in_dims']}-D descriptors to {v['out_dims']}-D"
            for role, v in sorted(models.items(), key=lambda kv: kv[0] != "seqnet") if isinstance(v, Mapping)
            and type(v.get("in_dims")) is int and type(v.get("out_dims")) is int
            and v["out_dims"] < v["in_dims"] and (v["out_dims"] * NARROW_SHARE <= v["in_dims"]
                                                  or v["out_dims"] < NARROW_DIMS)]
    if not said:
        return None
    return (f"{' and '.join(said)} (--out-dims): a layer this narrow loses much of what tells places apart; hint: "
            "train without --out-dims (out = D), or with a larger one; to save memory, reduce D with a PCA "
            "measured on val instead (seqnet train says what it costs)")


def barely_trained(models: Mapping[str, Any], narrow: bool = False) -> str | None:
    """A model whose checkpoint is from its first epoch though more were planned or run (``training`` of
    :func:`model_entries`): barely trained when its training loss did not fall to half of epoch 1's (the hint
    names only the optimiser settings it did not use), or fit to its training queries without generalising
    when it did (val R@1 never rose while the training loss fell; ``narrow``: a layer already narrow,
    :func:`narrow_layers`, is not told to take fewer weights); None otherwise."""
    said, fell, optimizers, lrs = [], False, set(), set()
    for role, v in sorted(models.items(), key=lambda kv: kv[0] != "seqnet"):
        t = v.get("training") if isinstance(v, Mapping) else None
        if not isinstance(t, Mapping) or t.get("epoch") != 1 or max(t.get("last_epoch", 1), t.get("epochs", 1)) < 2:
            continue
        ran = t.get("last_epoch")
        loss = t.get("loss") or {}
        after = f", training loss {loss[1]:.4f} at epoch 1, {loss[ran]:.4f} at {ran}" if ran and 1 in loss else ""
        fell = fell or bool(after and loss[ran] < loss[1] / 2)
        optimizers.add(t.get("optimizer"))
        lrs |= {f"{t['lr']:g}"} if "lr" in t else set()
        said.append(f"{role_label(role)}'s checkpoint is from epoch 1 of {ran or t['epochs']}"
                    f"{'' if ran else ' planned'} (val R@1 never rose after it{after})")
    if not said:
        return None
    if fell:
        fewer = "" if narrow else "fewer weights (a smaller --out-dims or --w), "  # never narrower than narrow
        return (f"{'; '.join(said)}: the model fit its training queries but did not generalise to val (or the "
                f"val split is too small to choose the epoch); hint: more training queries, {fewer}and a val split "
                "large enough to choose the epoch")
    options = [f"a larger --lr{f' (it was {next(iter(lrs))})' if len(lrs) == 1 else ''}",
               *([] if "adam" in optimizers else ["--optimizer adam"])]
    return (f"{'; '.join(said)}: the model is barely trained; hint: {' or '.join(options)}, and a val split large "
            "enough to choose the epoch")


def shortlist_capped(name: str, entry: Mapping[str, Any], baseline: float | None = None) -> str | None:
    """Why an HVPR's R@1 cannot rise: its shortlist of K holds a correct reference for at most one query more than
    its R@1 counts (the entry's ``shortlist_recall``) and less than the model-free ``baseline`` R@1 (when given: a
    shortlist that reaches it leaves the loss to the re-ranking), so the re-ranking is not what loses; or that recall
    is below the model-free ``baseline`` R@1 by a query or more, so no re-ranking of that shortlist reaches it (the
    re-ranking may lose too: said beside the other causes). None when the shortlist leaves room, or is not
    recorded."""
    cap, r1, queries = entry.get("shortlist_recall"), entry.get("recall@1"), entry.get("queries")
    if not isinstance(cap, Mapping) or not isinstance(r1, (int, float)) or not isinstance(cap.get("recall"), float):
        return None
    held = f"its shortlist ({parse_method(name).shortlist} top-{cap['k']}) holds a correct reference for only " \
        f"{cap['recall']:.3f} of the queries"
    hint = "a larger --top-k (or a better shortlist)"
    reaches = baseline is not None and queries_apart(cap["recall"], baseline, queries) < 1  # room up to the baseline
    if queries_apart(float(r1), cap["recall"], queries) <= 1 and not reaches:
        return f"{held}, which caps its R@1: the re-ranking is not what loses; {hint}"
    if baseline is not None and queries_apart(cap["recall"], baseline, queries) >= 1:
        return f"{held}, below the model-free {baseline:.3f}: no re-ranking of it reaches that; {hint}"
    return None


def queries_apart(low: float, high: float, queries: Any) -> float:
    """How many queries ``high`` is above ``low``: two recalls over the same ``queries`` are a whole number of
    queries apart (rounded: the recorded recalls may be rounded); in thousandths when the count is unknown."""
    apart = (high - low) / one_query(queries)
    return float(round(apart)) if isinstance(queries, int) and queries > 0 else apart


def within_chance(apart: int) -> bool:
    """Whether two methods ``apart`` queries apart in R@1 (on the same queries) may differ by chance: even when
    those are the only queries on which they differ, all one way (the most telling case), a two-sided sign test
    gives ``2 * 0.5**apart``, above 0.05 up to :data:`CHANCE_QUERIES`; true whatever the per-query answers."""
    return 0 <= apart <= CHANCE_QUERIES


def one_query(queries: Any) -> float:
    """What one query is of a recall over ``queries`` (``1 / queries``; 0.001 when the count is unknown)."""
    return 1.0 / queries if isinstance(queries, int) and queries > 0 else 0.001
