"""``seqnet describe IMAGES --method M --out FILE``: single-image descriptors of a folder, list file or ROS bag."""

from __future__ import annotations

import argparse

from ..core.errors import ConfigError
from ..describe import BACKBONES, DESCRIBERS, DescribeConfig, main
from ..describe.config import MAX_SIDE
from ..describe.merge import merge_shards
from ..describe.shards import resolve_shard, shard_output
from ..describe.views import VIEWS
from . import COMMANDS
from .common import add_device, add_topic, non_negative_int, positive_float, positive_int

_D = DescribeConfig()


def fit_source(text: str) -> str | int:
    """argparse type: an integer N (the first N input images) or a folder / list file."""
    return int(text) if text.isdigit() else text


def _table(entries: dict) -> str:
    return "; ".join(f"{name}: {entry.summary}" for name, entry in entries.items())


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "describe", help=COMMANDS["describe"],
        usage="%(prog)s IMAGES --method M --out FILE [--shard k/N] [options]\n"
              "       %(prog)s merge SHARD [SHARD ...] --out FILE [--overwrite]",
        description="Describe the images of a folder (sorted by name), a list file (one path per line, relative "
                    "to the list file), a ROS bag's image topic (--topic; in timestamp order) or a video file's "
                    "frames (--fps; named by their time) into an HDF5 file "
                    "(datasets 'descriptors', 'names') or a .npy with names "
                    "beside it. Interrupted runs resume when re-run with the same options. Past one machine: "
                    "--shard k/N describes the k-th (0-based) of N contiguous slices of the images (under torchrun, "
                    "RANK/WORLD_SIZE), and `seqnet describe merge SHARD... --out FILE` joins the N shard outputs "
                    "into the file one unsharded run writes (docs/describe.md).")
    p.add_argument("images", metavar="IMAGES", help="image folder, list file or ROS bag (with --topic), or 'merge' "
                   "followed by the shards")
    p.add_argument("shards", nargs="*", metavar="SHARD", help="merge: the shard outputs to merge, in any order")
    p.add_argument("--method", choices=list(DESCRIBERS), help=f"descriptor method, required ({_table(DESCRIBERS)})")
    p.add_argument("--out", required=True, metavar="FILE", help="output .h5/.hdf5 or .npy")
    p.add_argument("--shard", metavar="k/N", help="describe only the k-th of N contiguous slices of the images, "
                   "k = 0..N-1 (default under torchrun with WORLD_SIZE > 1: RANK/WORLD_SIZE, written to "
                   "<stem>.shard-k-of-N<suffix> beside --out); merge the N outputs with `seqnet describe merge`")
    add_topic(p)
    p.add_argument("--fps", type=positive_float, metavar="F", help="with a video file as IMAGES: frames described per "
                   "second of video time (default: every frame; frames are named by their time in seconds)")
    add_describe_options(p)
    p.add_argument("--overwrite", action="store_true", help="recompute an existing output (and its partial run)")
    add_device(p)
    p.set_defaults(func=run)


def add_describe_options(p: argparse.ArgumentParser, fit: bool = True) -> None:
    """The :class:`~seqnet.describe.DescribeConfig` options (not --method); ``fit``: also --fit-on/--fit-max."""
    p.add_argument("--resize", dest="size", metavar="WxH|keep-aspect:W|native|auto",
                   help=f"resize images to WxH (each side at most {MAX_SIDE}), to width W keeping the aspect ratio "
                        f"(keep-aspect:W), 'native' (keep their size) or 'auto' (default: {_auto_sizes()}; a "
                        "NetVLAD --checkpoint written by seqnet: the size it was fitted at)")
    p.add_argument("--crop-bottom", type=non_negative_int, metavar="ROWS",
                   help=f"rows removed from the bottom before resizing, e.g. a car bonnet (default {_D.crop_bottom})")
    p.add_argument("--batch-size", type=positive_int, help=f"images per batch (default {_D.batch_size})")
    p.add_argument("--dim", type=positive_int,
                   help="reduce descriptors to DIM with PCA (saved as <stem>.pca.npz beside the output)")
    p.add_argument("--whiten", action="store_true", help="whiten the PCA output")
    if fit:
        p.add_argument("--fit-on", dest="fit", type=fit_source, metavar="SRC|N",
                       help="images to fit PCA / NetVLAD clusters on: a folder or list file, or N for the first N "
                            "input images (default: up to --fit-max input images, evenly spaced)")
        p.add_argument("--fit-max", type=positive_int, help=f"default fitting set size (default {_D.fit_max})")
    p.add_argument("--patch", type=non_negative_int,
                   help=f"pixels: patch-normalisation size (default {_D.patch}, 0 = off)")
    p.add_argument("--backbone", choices=list(BACKBONES), help=f"CNN backbone (default {_D.backbone}; "
                   f"{_table(BACKBONES)})")
    p.add_argument("--layer", help="EfficientNet-Lite feature layer: 'head' or a block index (lite0: 0..15, "
                                   "lite1/lite2: 0..20; default: head for gem/gmp, the last stride-16 block for "
                                   "netvlad: 10 on lite0, 14 on lite1/lite2)")
    p.add_argument("--gem-p", type=positive_float, help=f"gem: pooling power p (default {_D.gem_p:g})")
    p.add_argument("--checkpoint", metavar="CKPT",
                   help="NetVLAD checkpoint (pytorch-NetVlad / Patch-NetVLAD format, e.g. pitts_WPCA4096.pth.tar); "
                        "gem/gmp then pool its encoder")
    p.add_argument("--describer", metavar="PKG.MODULE:FACTORY", help="--method plugin: your own describer, a "
                   "factory returning a torch module [B, 3, H, W] in [0, 1] -> [B, D] (docs/describe.md)")
    p.add_argument("--no-wpca", dest="use_wpca", action="store_false", help="netvlad: ignore the checkpoint's WPCA")
    p.add_argument("--clusters", type=positive_int, help=f"netvlad: clusters K when fitted (default {_D.clusters})")
    p.add_argument("--seed", type=non_negative_int, help=f"netvlad: k-means seed (default {_D.seed})")
    p.add_argument("--views", metavar="VIEW[,VIEW...]",
                   help=f"describe each image in these photometric views and concatenate their descriptors (D times "
                        f"the views): {', '.join(VIEWS)}, e.g. raw,equalize (default raw; docs/describe.md#views)")
    p.add_argument("--skip-corrupted", action="store_true", help="leave unreadable images out instead of failing")


DESCRIBE_KEYS = ("describer", "size", "crop_bottom", "batch_size", "dim", "whiten", "fit", "fit_max", "patch",
                 "backbone", "layer", "gem_p", "checkpoint", "use_wpca", "clusters", "seed", "skip_corrupted", "device",
                 "views")


def describe_config(args: argparse.Namespace) -> DescribeConfig:
    """The :class:`DescribeConfig` of the parsed options (unset ones keep the defaults)."""
    return _D.merge(method=args.method, **{k: getattr(args, k, None) for k in DESCRIBE_KEYS})


def _auto_sizes() -> str:
    """``native for pixels; 640x320 for gem, gmp, netvlad; ...`` from the methods' default sizes."""
    by_size: dict[str, list[str]] = {}
    for name, m in DESCRIBERS.items():
        if m.takes_describer:
            continue
        by_size.setdefault("x".join(map(str, m.default_size)) if m.default_size else "native", []).append(name)
    plugins = [n for n, m in DESCRIBERS.items() if m.takes_describer]
    return "; ".join([f"{size} for {', '.join(names)}" for size, names in by_size.items()]
                     + [f"the module's image_size (else native) for {', '.join(plugins)}"] * bool(plugins))


def run(args: argparse.Namespace) -> int:
    if args.images == "merge" and (args.shards or args.method is None):
        if args.method is not None or args.shard is not None:
            flag = "--method" if args.method is not None else "--shard"
            raise ConfigError(f"seqnet describe merge takes the shard files and --out (and --overwrite), not {flag}: "
                              "the shards record their settings")
        merge_shards(args.shards, args.out, overwrite=args.overwrite)  # logs what it wrote
        return 0
    if args.shards:
        raise ConfigError(f"seqnet describe takes one IMAGES folder or list file, got {1 + len(args.shards)} "
                          f"({args.images!r}, {args.shards[0]!r}, ...); hint: to merge shard outputs, "
                          "seqnet describe merge SHARD... --out FILE")
    if args.method is None:
        raise ConfigError(f"--method is required (one of {', '.join(DESCRIBERS)})")
    shard = resolve_shard(args.shard)
    out = shard_output(args.out, shard) if shard is not None and args.shard is None else args.out  # torchrun rank
    main(describe_config(args), args.images, out, overwrite=args.overwrite, shard=shard, topic=args.topic,
         fps=args.fps)
    return 0
