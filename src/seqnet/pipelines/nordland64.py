"""The Nordland64 benchmark: real 64×32 Nordland frames, summer (reference) vs winter (query).

Pipeline (:func:`main`): list the places (frames in the clean list, present in both seasons,
ordered by frame number; position = frame number / 10) → describe the images (cached in
``OUT/dataset``) → fit a PCA on the train range → train S_L and S_1 on the train range, selecting
the epoch on the val range → fold the PCA into the models (so they read the raw descriptors) →
evaluate every method on the test range → ``results.json``, ``results.md``, ``recall_at_k.png``.

Defaults: :data:`seqnet.presets.BENCHMARKS` ``["nordland64"]`` (tuned on the val range only).
"""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..config_legacy import merge
from ..data.io import load_dataset, save_dataset
from ..data.presets import BENCHMARKS
from ..data.traverse import Dataset, Traverse
from ..describe.pca import PCA, fit_pca
from ..errors import ConfigError, DatasetError
from ..evaluate import EvalConfig, Evaluation, evaluate
from ..files import save_npy_atomic, write_json_atomic
from ..sequence_descriptors import SeqNet
from ..utils import logger

SEASONS = ("summer", "winter")
FRAME_NUMBER = re.compile(r"(\d+)")


def resolve_config(overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The benchmark defaults merged with ``overrides`` (unknown keys raise :class:`ConfigError`)."""
    return merge(BENCHMARKS["nordland64"], overrides)


def list_places(data: str | Path, names_file: str = "nordland_clean_imageNames.txt") -> tuple[list[str], np.ndarray]:
    """Image names in the clean list present in both seasons, by frame number, and positions ``[N]`` (frame/10)."""
    root = Path(data)
    for sub in (*SEASONS, names_file):
        if not (root / sub).exists():
            raise DatasetError(f"{root} is not the nordland64 data: {sub} is missing "
                               f"(expected {', '.join(SEASONS)}/ and {names_file}; see docs/benchmark_nordland64.md)")
    clean = {line.strip() for line in (root / names_file).read_text(encoding="utf-8").splitlines() if line.strip()}
    present = {p.name for p in (root / SEASONS[0]).iterdir()} & {p.name for p in (root / SEASONS[1]).iterdir()}
    names = sorted(clean & present, key=lambda n: int(FRAME_NUMBER.findall(n)[-1]))
    if not names:
        raise DatasetError(f"{root}: no image of {names_file} is present in both {SEASONS[0]}/ and {SEASONS[1]}/")
    return names, np.array([int(FRAME_NUMBER.findall(n)[-1]) / 10.0 for n in names])


def describe_config(cfg: Mapping[str, Any]) -> dict[str, Any]:
    """The settings that determine the single-image descriptors (the cache key)."""
    return {"descriptor": cfg["descriptor"], "options": dict(cfg["descriptor_options"]),
            "fit_range": list(cfg["train_range"]) if cfg["descriptor"] != "pixels" else None,
            "flip_train": bool(cfg["flip"])}


def describe_seasons(data: Path, names: list[str], cfg: Mapping[str, Any], offset: int = 0) -> dict[str, np.ndarray]:
    """Descriptors ``[N, D]`` of the summer (reference) and winter (query) images of ``names``, and
    with ``cfg["flip"]`` of the horizontally flipped train images (``summer_flip``, ``winter_flip``).

    Anything fitted (NetVLAD clusters, PCA of the describer) is fitted on the train range only
    (``names[i]`` is place ``offset + i``).
    """
    from ..describe.describers import make_describer

    a, b = cfg["train_range"]
    fit = [data / s / n for s in SEASONS for n in names[a - offset : b - offset]]  # the train images
    describer = make_describer(cfg["descriptor"], fit, **{"fit": fit, **dict(cfg["descriptor_options"])})
    out, train_names = {}, names[a - offset : b - offset]
    for season in SEASONS:
        logger.info("describing %d %s images (%s)", len(names), season, cfg["descriptor"])
        desc, got = describer.describe([data / season / n for n in names], names)
        if len(got) != len(names):
            raise DatasetError(f"{len(names) - len(got)} {season} images could not be read")
        out[season] = desc
        if cfg["flip"]:
            out[f"{season}_flip"] = _describe_flipped(describer, [data / season / n for n in train_names])
    return out


def _describe_flipped(describer: Any, paths: list[Path], batch: int = 256) -> np.ndarray:
    """Descriptors ``[N, D]`` of the images ``paths`` mirrored left-right (training augmentation)."""
    from tqdm.auto import tqdm

    from ..describe.images import iter_batches, load_images

    size, out = describer.opts.resolved_size(describer.method), []
    for idx in tqdm(list(iter_batches(len(paths), batch)), desc="describe flipped", unit="batch", leave=False):
        imgs, _ = load_images([paths[i] for i in idx], size=size, crop_bottom=describer.opts.crop_bottom,
                              grey=describer.method == "pixels")
        out.append(describer(np.ascontiguousarray(imgs[:, :, ::-1])))
    return np.concatenate(out).astype(np.float32)


def _splits(cfg: Mapping[str, Any], n: int) -> tuple[int, dict[str, dict[str, tuple[int, int]]]]:
    """The first place used and the splits relative to it (only the places in use are described)."""
    ranges = {}
    for split in ("train", "val", "test"):
        a, b = (int(x) for x in cfg[f"{split}_range"])
        if not 0 <= a < b <= n:
            raise ConfigError(f"--{split}-range {a}:{b} is outside 0:{n} (the {n} nordland64 places) or empty")
        ranges[split] = (a, b)
    lo = min(a for a, _ in ranges.values())
    return lo, {k: {"reference": (a - lo, b - lo), "query": (a - lo, b - lo)} for k, (a, b) in ranges.items()}


def build_dataset(data: str | Path, cfg: Mapping[str, Any], out: Path) -> tuple[Dataset, np.ndarray | None]:
    """The nordland64 dataset (raw descriptors, places in use, splits), cached in ``out/dataset``, and
    the flipped train descriptors ``[2, n_train, D]`` (summer, winter; None without ``cfg["flip"]``)."""
    data = Path(data)
    names, pos = list_places(data, cfg["names_file"])
    lo, splits = _splits(cfg, len(names))
    hi = lo + max(r["query"][1] for r in splits.values())
    names, pos = names[lo:hi], pos[lo:hi]
    key = describe_config(cfg)
    cache = out / "dataset"
    if (cache / "dataset.json").is_file():
        ds = load_dataset(cache, mmap=False)
        flip_ok = not cfg["flip"] or (cache / "flip_train.npy").is_file()
        if ds.extra.get("describe") == json.loads(json.dumps(key)) and ds.reference.names == names and flip_ok:
            logger.info("using cached descriptors in %s", cache)
            ds.splits = splits
            return ds, np.load(cache / "flip_train.npy") if cfg["flip"] else None
    t0 = time.perf_counter()
    d = describe_seasons(data, names, cfg, lo)
    ds = Dataset(reference=Traverse(d["summer"], pos, names=names, name="summer"),
                 query=Traverse(d["winter"], pos, names=list(names), name="winter"), radius=float(cfg["radius"]),
                 position_unit="frames", splits=splits, name="nordland64",
                 extra={"pos_radius": cfg["pos_radius"], "neg_radius": cfg["neg_radius"], "describe": key,
                        "describe_seconds": round(time.perf_counter() - t0, 2), "source": str(data),
                        "first_place": lo})
    save_dataset(ds, cache, overwrite=True)
    flipped = np.stack([d["summer_flip"], d["winter_flip"]]) if cfg["flip"] else None
    if flipped is not None:
        save_npy_atomic(cache / "flip_train.npy", flipped)
    return ds, flipped


def training_dataset(ds: Dataset, pca: PCA | None, symmetric: bool, flipped: np.ndarray | None = None) -> Dataset:
    """The train + val splits of ``ds`` (descriptors PCA-projected) for :func:`seqnet.train.train`.

    With ``symmetric``, the train range is used both ways (winter → summer and summer → winter);
    ``flipped`` ``[2, n_train, D]`` (summer, winter descriptors of the mirrored train images) adds
    the mirrored route. Each is its own sequence, far from the others in position; the val split
    stays winter → summer.
    """
    (a, b), (c, d) = ds.splits["train"]["query"], ds.splits["val"]["query"]

    def proj(x: np.ndarray) -> np.ndarray:
        return np.asarray(x, dtype=np.float32) if pca is None else pca.transform(x, l2=False)

    r, q, p = proj(ds.reference.descriptors), proj(ds.query.descriptors), ds.reference.positions[:, 0]
    pairs = [(r[a:b], q[a:b])] + ([(proj(flipped[0]), proj(flipped[1]))] if flipped is not None else [])
    pairs += [(y, x) for x, y in pairs] if symmetric else []
    gap = 10 * float(p.max()) + 100  # positions of different sequences never within a radius
    parts = [(x, y, p[a:b] + i * gap) for i, (x, y) in enumerate(pairs)] + [(r[c:d], q[c:d], p[c:d])]
    sizes = np.cumsum([0] + [len(x[0]) for x in parts])
    bounds = np.concatenate([np.tile([[s, e]], (e - s, 1)) for s, e in zip(sizes[:-1], sizes[1:], strict=True)])
    ref = Traverse(np.concatenate([x[0] for x in parts]), np.concatenate([x[2] for x in parts]), seq_bounds=bounds)
    qry = Traverse(np.concatenate([x[1] for x in parts]), np.concatenate([x[2] for x in parts]), seq_bounds=bounds)
    n_train, n_all = int(sizes[-2]), int(sizes[-1])
    splits = {"train": {"reference": (0, n_train), "query": (0, n_train)},
              "val": {"reference": (n_train, n_all), "query": (n_train, n_all)}}
    return Dataset(ref, qry, radius=ds.radius, position_unit="frames", splits=splits, name="nordland64-train",
                   extra={"pos_radius": ds.extra["pos_radius"], "neg_radius": ds.extra["neg_radius"]})


def fold_pca(model: SeqNet, pca: PCA) -> SeqNet:
    """A SeqNet on raw descriptors equal to ``model(pca.transform(x, l2=False))``.

    The PCA ``y = s ⊙ (C (x − μ))`` is linear, so it merges into the first convolution:
    ``W'_k = W_k · diag(s) C`` and ``b' = b − Σ_k W'_k μ``.
    """
    proj = torch.from_numpy(pca.components * pca.scales[:, None]).double()  # [p, D]
    w = model.conv.weight.detach().double()  # [D_out, p, w]
    w_new = torch.einsum("opk,pd->odk", w, proj)  # [D_out, D, w]
    b_new = model.conv.bias.detach().double() - torch.einsum("odk,d->o", w_new, torch.from_numpy(pca.mean).double())
    out = SeqNet(pca.input_dim, model.out_dims, model.seq_len, model.w)
    with torch.no_grad():
        out.conv.weight.copy_(w_new.float())
        out.conv.bias.copy_(b_new.float())
    return out.eval()


def _train_key(cfg: Mapping[str, Any]) -> str:
    keys = ("train_range", "val_range", "pca_dims", "pca_whiten", "symmetric", "flip", "pos_radius", "neg_radius",
            "train", "train_s1", "names_file")
    blob = json.dumps({"describe": describe_config(cfg), **{k: cfg[k] for k in keys}}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def fit_train_pca(ds: Dataset, cfg: Mapping[str, Any]) -> PCA | None:
    """PCA to ``cfg["pca_dims"]`` (capped by the data) of both seasons' train descriptors; None when 0."""
    if not cfg["pca_dims"]:
        return None
    a, b = ds.splits["train"]["query"]
    x = np.concatenate([ds.reference.descriptors[a:b], ds.query.descriptors[a:b]])
    dims = min(int(cfg["pca_dims"]), *x.shape)
    if dims < int(cfg["pca_dims"]):
        logger.warning("PCA: %d dims asked, %d possible with %d training images", cfg["pca_dims"], dims, len(x))
    return fit_pca(x, dims, whiten=bool(cfg["pca_whiten"]), l2=False)


def train_models(ds: Dataset, cfg: Mapping[str, Any], out: Path,
                 flipped: np.ndarray | None = None) -> tuple[dict[str, SeqNet], dict[str, float]]:
    """Train S_L and S_1 (PCA-projected inputs, epoch chosen on val), fold the PCA in; save to ``out/models``.

    Models trained with the same settings before (``out/models/key.json``) are reused.
    """
    from ..checkpoints import load_model, save_checkpoint
    from ..train.loop import train

    models_dir, key = out / "models", _train_key(cfg)
    key_file = models_dir / "key.json"
    if key_file.is_file() and json.loads(key_file.read_text()).get("key") == key:
        logger.info("reusing the models trained with the same settings in %s", models_dir)
        info = json.loads(key_file.read_text())
        return {r: load_model(models_dir / f"{r}.pt") for r in ("seqnet", "s1")}, info["seconds"]
    pca = fit_train_pca(ds, cfg)
    if pca is not None:
        pca.save(models_dir / "pca.npz")
    tds = training_dataset(ds, pca, bool(cfg["symmetric"]), flipped)
    models, seconds = {}, {}
    for role, tcfg in (("seqnet", cfg["train"]), ("s1", {**cfg["train"], **cfg["train_s1"]})):
        run_dir = out / "runs" / role
        shutil.rmtree(run_dir, ignore_errors=True)
        logger.info("training %s (%s) on places %s", role, "S_1" if role == "s1" else "S_L", cfg["train_range"])
        t0 = time.perf_counter()
        run = train(tds, {**tcfg, "device": cfg["device"]}, run_dir)
        seconds[role] = round(time.perf_counter() - t0, 2)
        model = load_model(run_dir / "best.pt")
        models[role] = fold_pca(model, pca) if pca is not None else model
        save_checkpoint(models_dir / f"{role}.pt", models[role], epoch=run.best_epoch, best_score=run.best_score,
                        metrics={"val_recall@1": run.best_score}, config={**tcfg, "pca_folded": pca is not None})
        logger.info("%s: best val R@1 %.3f at epoch %d (%.0f s)", role, run.best_score, run.best_epoch, seconds[role])
    write_json_atomic(key_file, {"key": key, "seconds": seconds})
    return models, seconds


def evaluate_split(ds: Dataset, models: Mapping[str, SeqNet], cfg: Mapping[str, Any], split: str) -> Evaluation:
    """Every benchmark method on one split (centred L-frame windows; ``hvpr-*`` re-rank with S_1)."""
    conf = EvalConfig(methods=tuple(cfg["methods"]), seq_len=cfg["seq_len"], ks=tuple(cfg["ks"]), top_k=cfg["top_k"],
                      device=cfg["device"])
    return evaluate(ds.split(split), conf, models)


def write_report(ev: Evaluation, val: Evaluation, cfg: Mapping[str, Any], seconds: Mapping[str, float],
                 out: Path) -> None:
    """``results.json`` (eval schema + benchmark config and timings), ``val_results.json``,
    ``results.md`` (Table-I style) and ``recall_at_k.png`` (Recall@K, K = 1..20, test range)."""
    from ..files import write_text_atomic
    from ..recall import recall_curve
    from ..report import format_markdown, plot_recall_curves

    ev.results["config"].update(benchmark=dict(cfg), timings_s=dict(seconds))
    write_json_atomic(out / "results.json", ev.results)
    write_json_atomic(out / "val_results.json", val.results)
    curves = {m: recall_curve(r, ev.truth, 20) for m, r in ev.retrieved.items()}
    plot_recall_curves(curves, out / "recall_at_k.png", title=f"Nordland64 test (L={cfg['seq_len']})")
    first = next(iter(ev.results["methods"].values()))
    (a, b), (c, d) = cfg["test_range"], cfg["val_range"]
    lines = [
        "# Nordland64 benchmark results", "",
        f"Reference summer, query winter; test places {a}:{b} ({first['queries']} queries with a full "
        f"L={cfg['seq_len']} window); radius {cfg['radius']:g} (frame steps); descriptor `{cfg['descriptor']}`.", "",
        format_markdown(ev.results["methods"], ks=(1, 5, 20)),
        f"Validation (places {c}:{d}, used to select epochs and settings), R@1: "
        + ", ".join(f"{m} {r['recall@1']:.3f}" for m, r in val.results["methods"].items()), "",
        "Timings (s): " + ", ".join(f"{k} {v:.1f}" for k, v in seconds.items()), "",
    ]
    write_text_atomic(out / "results.md", "\n".join(lines))


def main(conf: Mapping[str, Any] | None, data: str | Path, out: str | Path) -> Evaluation:
    """Run the benchmark (hloc style): ``conf`` overrides the defaults; writes everything to ``out``.

    Returns the test-range :class:`Evaluation` (``results`` in the ``--json`` schema).
    """
    cfg = resolve_config(conf)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    seconds: dict[str, float] = {}
    ds, flipped = build_dataset(data, cfg, out)
    seconds["descriptors"] = round(time.perf_counter() - t0, 2)
    logger.info("nordland64: %d places, D=%d; train %s, val %s, test %s", len(ds.query), ds.query.dim,
                cfg["train_range"], cfg["val_range"], cfg["test_range"])
    models, train_s = train_models(ds, cfg, out, flipped)
    seconds.update({f"train_{k}": v for k, v in train_s.items()})
    t1 = time.perf_counter()
    val = evaluate_split(ds, models, cfg, "val")
    ev = evaluate_split(ds, models, cfg, "test")
    seconds["evaluation"] = round(time.perf_counter() - t1, 2)
    seconds["total"] = round(time.perf_counter() - t0, 2)
    write_report(ev, val, cfg, seconds, out)
    write_json_atomic(out / "config.json", {**cfg, "data": str(data)})
    logger.info("nordland64 done in %.0f s: %s", seconds["total"], out / "results.md")
    return ev
