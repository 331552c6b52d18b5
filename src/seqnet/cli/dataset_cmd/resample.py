"""``seqnet dataset resample``: a dataset with every N-th frame of a side kept (fixed-time sampling)."""

from __future__ import annotations

import argparse

from ..common import positive_int

RESAMPLE_HELP = ("keep every N-th frame of the recorded order, whatever the distance travelled (fixed-time "
                 "sampling: the paper's Oxford-FT test keeps every 6th frame)")
SIDES = ("query", "reference", "both")  # seqnet.data.resample.RESAMPLE_SIDES, without importing numpy here


def add_resample_options(p: argparse.ArgumentParser, every: str = "--resample-every",
                         side: str = "--resample-side") -> None:
    """The two options of fixed-time re-sampling: ``every`` (N) and ``side`` (query, reference, both)."""
    p.add_argument(every, type=positive_int, metavar="N", help=RESAMPLE_HELP)
    p.add_argument(side, choices=SIDES, default="query", help="the side re-sampled (default query)")


def register_resample(dsub: argparse._SubParsersAction) -> None:
    p = dsub.add_parser("resample", help="keep every N-th frame of a side (fixed-time sampling)",
                        description="Write a dataset that keeps frames 0, N, 2N, ... of the query side, the "
                                    "reference side or both, in recorded order: descriptors, positions, names, "
                                    "sequence bounds, splits and explicit positives re-indexed alike; the "
                                    "re-sampling is recorded in dataset.json ('resample'). docs/datasets.md.")
    p.add_argument("dir", metavar="DIR", help="seqnet dataset directory")
    p.add_argument("--every", type=positive_int, required=True, metavar="N", help=RESAMPLE_HELP)
    p.add_argument("--side", choices=SIDES, default="query", help="the side re-sampled (default query)")
    p.add_argument("--out", required=True, metavar="OUT", help="output dataset directory")
    p.add_argument("--name", help="dataset name (default: DIR's name with '-every<N>')")
    p.add_argument("--overwrite", action="store_true", help="replace OUT if seqnet wrote it")
    p.set_defaults(func=run_resample)


def run_resample(args: argparse.Namespace) -> int:
    import dataclasses

    from ...core.log import logger, ordinal
    from ...data.io import load_dataset, save_dataset
    from ...data.resample import resample_dataset
    from ...pipelines.ground_truth import check_true_matches

    ds = load_dataset(args.dir)
    out = resample_dataset(ds, args.every, args.side)
    out = dataclasses.replace(out, name=args.name or f"{ds.name}-every{args.every}")
    check_true_matches(out)  # a reference thinned below the radius: refused, nothing written; few: one warning
    save_dataset(out, args.out, overwrite=args.overwrite, quiet=True)  # said below, with the counts
    sides = "both sides" if args.side == "both" else f"the {args.side} side"
    logger.info("wrote %s: %d reference / %d query frames (from %d / %d, every %s frame of %s)", args.out,
                len(out.reference), len(out.query), len(ds.reference), len(ds.query), ordinal(args.every), sides)
    return 0
