"""Synthetic route data for tests and the demo.

A route of ``places`` places is traversed twice (reference, query). Each place has a latent
appearance that varies smoothly along the route; some stretches repeat others (perceptual
aliasing). Each traverse moves at its own varying speed (frames do not align one-to-one), is cut
into a few sequences (sequence bounds), and sees every place through its own condition (a fixed
random linear change of appearance, like day vs night) plus strong per-frame noise. Single
images are hard to match; windows of frames average the noise out, so sequence methods help.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from ..core.config import Config, check_float, check_int
from ..core.provenance import make as make_provenance
from .io import save_dataset
from .traverse import Dataset, Traverse

PLACE_SPACING_M = 2.0
RADIUS_M = 5.0


@dataclasses.dataclass(frozen=True)
class SynthConfig(Config):
    """Settings of :func:`make_synthetic`.

    Attributes:
        places: number of places along the route (>= 100).
        dim: descriptor dimension D (>= 8).
        seed: random seed (the same seed gives the same dataset).
        noise: per-frame noise level relative to the place signal (isotropic, independent per frame).
        nuisance: strength of the slowly varying, condition-specific appearance change that lives in a
            few directions shared by both traverses (averaging a window cannot remove it; a learned
            projection can).
    """

    places: int = 600
    dim: int = 64
    seed: int = 0
    noise: float = 1.5
    nuisance: float = 1.0

    def __post_init__(self) -> None:
        self._set("places", check_int("places", self.places, 100))
        self._set("dim", check_int("dim", self.dim, 8))
        self._set("seed", check_int("seed", self.seed, 0))
        self._set("noise", check_float("noise", self.noise, 0.0, strict=True))
        self._set("nuisance", check_float("nuisance", self.nuisance, 0.0))


def _latent_route(rng: np.random.Generator, places: int, dim: int, rho: float = 0.8) -> np.ndarray:
    """``[places, dim]`` smooth AR(1) appearance along the route, with aliased stretches."""
    z = np.empty((places, dim))
    z[0] = rng.standard_normal(dim)
    eps = rng.standard_normal((places, dim)) * np.sqrt(1 - rho**2)
    for p in range(1, places):
        z[p] = rho * z[p - 1] + eps[p]
    seg = max(4, places // 40)
    for _ in range(max(1, places // (4 * seg))):  # about a quarter of places look like others
        src, dst = rng.integers(0, places - seg, size=2)
        if abs(int(src) - int(dst)) > 2 * seg:
            z[dst : dst + seg] = 0.85 * z[src : src + seg] + 0.15 * z[dst : dst + seg]
    return z


def _route_xy(places: int) -> np.ndarray:
    """``[places, 2]`` easting/northing of a winding route, places ``PLACE_SPACING_M`` apart."""
    t = np.arange(places)
    heading = 0.6 * np.sin(t / 25.0) + 0.3 * np.sin(t / 7.0)
    steps = PLACE_SPACING_M * np.stack([np.cos(heading), np.sin(heading)], axis=1)
    return 500000.0 + np.cumsum(steps, axis=0) + np.array([0.0, 6.0e6])


def _nuisance(rng: np.random.Generator, n: int, basis: np.ndarray, rho: float = 0.97) -> np.ndarray:
    """``[n, D]`` slowly varying appearance change (lighting, weather) inside the span of ``basis [k, D]``."""
    c = np.empty((n, len(basis)))
    c[0] = rng.standard_normal(len(basis))
    eps = rng.standard_normal(c.shape) * np.sqrt(1 - rho**2)
    for i in range(1, n):
        c[i] = rho * c[i - 1] + eps[i]
    return c @ basis


def _traverse(
    rng: np.random.Generator, z: np.ndarray, xy: np.ndarray, noise: float, condition: np.ndarray, name: str,
    nuisance: np.ndarray,
) -> tuple[Traverse, np.ndarray]:
    places = len(z)
    wave = 0.25 * np.sin(np.arange(4 * places) / rng.uniform(15, 30))
    speed = np.clip(1.0 + wave + 0.1 * rng.standard_normal(4 * places), 0.6, 1.5)
    route_pos = np.concatenate([[0.0], np.cumsum(speed)])
    route_pos = route_pos[route_pos <= places - 1]
    lo = np.floor(route_pos).astype(int)
    hi = np.minimum(lo + 1, places - 1)
    frac = (route_pos - lo)[:, None]
    latent = (1 - frac) * z[lo] + frac * z[hi]
    xy_f = (1 - frac) * xy[lo] + frac * xy[hi]
    desc = latent @ condition + _nuisance(rng, len(latent), nuisance) + noise * rng.standard_normal(latent.shape)
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    n = len(route_pos)
    cuts = np.sort(rng.choice(np.arange(n // 8, n - n // 8), size=3, replace=False))
    edges = np.concatenate([[0], cuts, [n]])
    bounds = np.zeros((n, 2), dtype=np.int64)
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        bounds[a:b] = (a, b)
    names = [f"{name}_{i:06d}.png" for i in range(n)]
    return Traverse(desc.astype(np.float32), xy_f, names, bounds, name), route_pos


def make_synthetic(conf: SynthConfig | None = None, **overrides: Any) -> Dataset:
    """Build a synthetic dataset (UTM positions in metres, radius 5 m, train/val/test splits).

    ``overrides`` change fields of ``conf`` (default :class:`SynthConfig`), e.g. ``make_synthetic(places=200)``.
    """
    conf = (conf or SynthConfig()).merge(**overrides)
    places, noise, nuisance = conf.places, conf.noise, conf.nuisance
    rng = np.random.default_rng(conf.seed)
    z = _latent_route(rng, conf.places, conf.dim)
    xy = _route_xy(conf.places)
    eye = np.eye(conf.dim)
    ref_cond = eye + 0.3 * rng.standard_normal(eye.shape) / np.sqrt(conf.dim)
    qry_cond = eye * rng.uniform(0.3, 1.7, conf.dim) + 0.8 * rng.standard_normal(eye.shape) / np.sqrt(conf.dim)
    k = max(2, conf.dim // 8)
    basis = np.linalg.qr(rng.standard_normal((conf.dim, k)))[0].T * nuisance * np.sqrt(conf.dim / k)
    ref, ref_route = _traverse(rng, z, xy, noise, ref_cond, "reference", basis)
    qry, qry_route = _traverse(rng, z, xy, noise, qry_cond, "query", basis)
    ref.provenance = qry.provenance = make_provenance("synthetic", conf.to_dict(), dim=conf.dim)
    splits = {}
    for split, (a, b) in {"train": (0.0, 0.6), "val": (0.6, 0.75), "test": (0.75, 1.0)}.items():
        rng_r = np.searchsorted(ref_route, [a * (places - 1), b * (places - 1)])
        rng_q = np.searchsorted(qry_route, [a * (places - 1), b * (places - 1)])
        splits[split] = {"reference": (int(rng_r[0]), int(rng_r[1])), "query": (int(rng_q[0]), int(rng_q[1]))}
    return Dataset(
        reference=ref, query=qry, radius=RADIUS_M, position_unit="metres", splits=splits, name="synthetic",
        extra={"pos_radius": RADIUS_M, "neg_radius": 4 * RADIUS_M, "source": f"seqnet synth (seed {conf.seed})"},
    )


def main(conf: SynthConfig, out: str | Path, overwrite: bool = False, quiet: bool = False) -> Path:
    """Write the synthetic dataset of ``conf`` to the directory ``out`` (hloc-style stage); ``quiet``: the line
    saying so is DEBUG (the caller says it)."""
    return save_dataset(make_synthetic(conf), out, overwrite=overwrite, quiet=quiet)
