"""``seqnet synth DIR``: write a synthetic dataset in the directory format."""

from __future__ import annotations

import argparse

from ..data.synth import SynthConfig, main
from . import COMMANDS
from .common import int_at_least, non_negative_float, non_negative_int, positive_float

_D = SynthConfig()


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("synth", help=COMMANDS["synth"])
    p.add_argument("out", metavar="DIR", help="output dataset directory")
    p.add_argument("--places", type=int_at_least(100), help=f"places along the route (default {_D.places})")
    p.add_argument("--dim", type=int_at_least(8), help=f"descriptor dimension (default {_D.dim})")
    p.add_argument("--noise", type=positive_float, help=f"per-frame noise level (default {_D.noise})")
    p.add_argument("--nuisance", type=non_negative_float,
                   help=f"slowly varying appearance change between traverses (default {_D.nuisance})")
    p.add_argument("--seed", type=non_negative_int, help=f"random seed (default {_D.seed})")
    p.add_argument("--overwrite", action="store_true", help="replace DIR if it exists")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    conf = SynthConfig().merge(places=args.places, dim=args.dim, seed=args.seed, noise=args.noise,
                                 nuisance=args.nuisance)
    out = main(conf, args.out, overwrite=args.overwrite, quiet=True)  # said below, once
    from ..data.io import load_dataset

    ds = load_dataset(out)
    print(f"wrote {out}: reference {len(ds.reference)} and query {len(ds.query)} frames, D={ds.query.dim}, "
          f"radius {ds.radius:g} m, splits {', '.join(ds.splits)}")
    return 0
