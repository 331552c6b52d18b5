"""``seqnet synth DIR``: write a synthetic dataset in the directory format."""

from __future__ import annotations

import argparse

from ..config import SYNTH_DEFAULTS
from ..dataset_io import save_dataset
from ..synth import make_synthetic
from .common import positive_float, positive_int


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("synth", help="write a synthetic dataset (route traversed twice, hard appearance change)")
    p.add_argument("out", metavar="DIR", help="output dataset directory")
    p.add_argument("--places", type=positive_int, default=SYNTH_DEFAULTS["places"],
                   help=f"places along the route (default {SYNTH_DEFAULTS['places']})")
    p.add_argument("--dim", type=positive_int, default=64, help="descriptor dimension (default 64)")
    p.add_argument("--noise", type=positive_float, default=SYNTH_DEFAULTS["noise"],
                   help=f"per-frame noise level (default {SYNTH_DEFAULTS['noise']})")
    p.add_argument("--nuisance", type=float, default=SYNTH_DEFAULTS["nuisance"],
                   help=f"slowly varying appearance change between traverses (default {SYNTH_DEFAULTS['nuisance']})")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--overwrite", action="store_true", help="replace DIR if it exists")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    ds = make_synthetic(places=args.places, dim=args.dim, seed=args.seed, noise=args.noise,
                        nuisance=args.nuisance)
    save_dataset(ds, args.out, overwrite=args.overwrite)
    print(f"wrote {args.out}: reference {len(ds.reference)} and query {len(ds.query)} frames, D={ds.query.dim}, "
          f"radius {ds.radius:g} m, splits {', '.join(ds.splits)}")
    return 0
