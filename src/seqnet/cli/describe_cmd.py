"""``seqnet describe IMAGES --method M --out FILE``: single-image descriptors of a folder or list file."""

from __future__ import annotations

import argparse

from ..describe.describers import METHODS, describe_folder
from ..utils import set_threads
from .common import add_device, positive_float, positive_int


def image_size(text: str) -> tuple[int, int] | None:
    """argparse type: ``WxH`` (e.g. 640x320) or ``native``."""
    if text.lower() == "native":
        return None
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT (e.g. 640x320) or 'native', got {text!r}") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"expected a width and height >= 1, got {text!r}")
    return w, h


def fit_source(text: str) -> str | int:
    """argparse type: an integer N (the first N input images) or a folder / list file."""
    return int(text) if text.isdigit() else text


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "describe", help="compute single-image descriptors (pixels, GeM, GMP, NetVLAD) of an image folder",
        description="Describe the images of a folder (sorted by name) or a list file (one path per line, relative "
                    "to the list file) into an HDF5 file (datasets 'descriptors', 'names') or a .npy with names "
                    "beside it. Interrupted runs resume when re-run with the same options.")
    p.add_argument("images", metavar="IMAGES", help="image folder or list file")
    p.add_argument("--method", required=True, choices=METHODS, help="descriptor method")
    p.add_argument("--out", required=True, metavar="FILE", help="output .h5/.hdf5 or .npy")
    p.add_argument("--resize", type=image_size, metavar="WxH",
                   help="resize images to WxH, or 'native' (default: native for pixels, 640x320 for CNN methods)")
    p.add_argument("--crop-bottom", type=int, default=0, metavar="ROWS",
                   help="rows removed from the bottom before resizing (e.g. a car bonnet)")
    p.add_argument("--batch-size", type=positive_int, default=8, help="images per batch (default 8)")
    p.add_argument("--dim", type=positive_int,
                   help="reduce descriptors to DIM with PCA (saved as <stem>.pca.npz beside the output)")
    p.add_argument("--whiten", action="store_true", help="whiten the PCA output")
    p.add_argument("--fit-on", type=fit_source, metavar="SRC|N",
                   help="images to fit PCA / NetVLAD clusters on: a folder or list file, or N for the first N "
                        "input images (default: up to --fit-max input images, evenly spaced)")
    p.add_argument("--fit-max", type=positive_int, default=1000, help="default fitting set size (default 1000)")
    p.add_argument("--patch", type=int, default=8, help="pixels: patch-normalisation size (default 8, 0 = off)")
    p.add_argument("--backbone", default="efficientnet-lite0", choices=["efficientnet-lite0", "vgg16"],
                   help="CNN backbone (default efficientnet-lite0, ImageNet weights shipped with its package)")
    p.add_argument("--layer", help="efficientnet-lite0 feature layer: 'head' or block index 0..15 "
                                   "(default: head for gem/gmp, 10 for netvlad)")
    p.add_argument("--gem-p", type=positive_float, default=3.0, help="gem: pooling power p (default 3)")
    p.add_argument("--checkpoint", metavar="CKPT",
                   help="NetVLAD checkpoint (pytorch-NetVlad / Patch-NetVLAD format, e.g. pitts_WPCA4096.pth.tar); "
                        "gem/gmp then pool its encoder")
    p.add_argument("--no-wpca", dest="use_wpca", action="store_false", help="netvlad: ignore the checkpoint's WPCA")
    p.add_argument("--clusters", type=positive_int, default=64, help="netvlad: clusters K when fitted (default 64)")
    p.add_argument("--skip-corrupted", action="store_true", help="leave unreadable images out instead of failing")
    p.add_argument("--overwrite", action="store_true", help="recompute an existing output (and its partial run)")
    p.add_argument("--threads", type=positive_int, help="torch CPU threads (default: torch's)")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="hide the progress bar")
    add_device(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    set_threads(args.threads)
    layer = int(args.layer) if args.layer and args.layer.isdigit() else args.layer
    options = dict(
        size="auto" if args.resize is None else args.resize, crop_bottom=args.crop_bottom,
        batch_size=args.batch_size, dim=args.dim, whiten=args.whiten, fit=args.fit_on, fit_max=args.fit_max,
        patch=args.patch, backbone=args.backbone, layer=layer, gem_p=args.gem_p, checkpoint=args.checkpoint,
        use_wpca=args.use_wpca, clusters=args.clusters, skip_corrupted=args.skip_corrupted,
        progress=args.progress, device=args.device,
    )
    describe_folder(args.images, args.method, out=args.out, overwrite=args.overwrite, **options)  # logs what it wrote
    return 0
