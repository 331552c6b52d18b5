"""``seqnet index build``: prepare a dataset's reference side once as a map (index + re-ranking frames)."""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path

from ..maps import MapConfig, build, load_map
from ..maps.config import DTYPES
from ..maps.coverage import coverage_line
from ..methods.grammar import FRAME_FEATURES
from ..search.ann import ANN_INDEXES, AnnConfig
from ..sequence.descriptors import DESCRIPTOR_ALIASES, SEQUENCE_DESCRIPTORS
from ..sequence.windows import WINDOW_MODES
from . import COMMANDS
from .common import add_allow_mismatch, add_device, drop_none, non_negative_int, positive_int

_D, _A = MapConfig(), AnnConfig()


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("index", help=COMMANDS["index"])
    isub = p.add_subparsers(dest="index_command", metavar="ACTION", required=True)
    b = isub.add_parser("build", help="describe a dataset's reference side and save it as a map directory",
                        description="Describe the reference side of a dataset split with the given models and save "
                                    "a self-contained map: shortlist descriptors + ANN index, re-ranking frame "
                                    "descriptors (memory-mapped at use), positions, names, models, config and "
                                    "provenance (docs/scale.md). Use it with `seqnet eval --index MAP`.")
    b.add_argument("--dataset", required=True, help="seqnet dataset directory")
    b.add_argument("--split", help="split whose reference side is mapped (default: test when defined, else all)")
    b.add_argument("--model", action="append", default=[], metavar="CKPT",
                   help="model checkpoint (S_L and/or S_1, by their stored role); repeatable")
    b.add_argument("--shortlist", choices=[*SEQUENCE_DESCRIPTORS, *DESCRIPTOR_ALIASES],
                   help=f"shortlist descriptor (default {_D.shortlist})")
    b.add_argument("--rerank", metavar="FRAMES+MATCHER",
                   help=f"re-ranking frames and matcher, frames one of {', '.join(FRAME_FEATURES)} "
                        f"(default {_D.rerank})")
    b.add_argument("--seq-len", type=positive_int, help="L (default: the S_L model's, else 5)")
    b.add_argument("--match-len", "--rerank-seq-len", dest="match_len", type=positive_int,
                   help="L_m (default: L; --rerank-seq-len: its earlier name)")
    b.add_argument("--window", choices=WINDOW_MODES, help=f"window position (default {_D.window})")
    b.add_argument("--index", dest="kind", metavar="KIND",
                   help=f"index over the shortlist descriptors: {', '.join(ANN_INDEXES)} (default {_A.kind}: exact "
                   "search), or any FAISS index_factory string, e.g. 'OPQ16,IVF1024,PQ16' or 'HNSW32,SQ8'")
    b.add_argument("--nlist", type=positive_int, help="IVF lists (default about 4·sqrt(N))")
    b.add_argument("--nprobe", type=positive_int, help=f"IVF lists visited per query (default {_A.nprobe})")
    b.add_argument("--hnsw-m", type=positive_int, help=f"HNSW neighbours per node (default {_A.hnsw_m})")
    b.add_argument("--ef-search", type=positive_int, help=f"HNSW search breadth (default {_A.ef_search})")
    b.add_argument("--ef-construction", type=positive_int, help=f"HNSW build breadth (default {_A.ef_construction})")
    b.add_argument("--pq-m", type=positive_int, help=f"IVF-PQ sub-quantisers, dividing D (default {_A.pq_m})")
    b.add_argument("--pq-bits", type=positive_int, help=f"IVF-PQ bits per code (default {_A.pq_bits})")
    b.add_argument("--seed", type=non_negative_int, help=f"k-means seed (default {_A.seed})")
    b.add_argument("--shards", type=positive_int, help="IVF indexes only: train one coarse quantizer, build the "
                   "inverted lists of N contiguous shards of the items in parallel and merge them on disk "
                   "(index.ivfdata, opened memory-mapped); same results as one index (default 1)")
    b.add_argument("--top-k", type=positive_int, help="HVPR K stored in the map for localize --map, serve, eval "
                   "--index (default: chosen on val as seqnet eval does; 20 without val, or for --split all)")
    b.add_argument("--dtype", choices=DTYPES, help=f"storage of the descriptors (default {_D.dtype})")
    b.add_argument("--out", required=True, metavar="MAP", help="map directory to write (replaced only when it "
                   "holds nothing but a seqnet map)")
    add_allow_mismatch(b)
    add_device(b)
    b.set_defaults(func=run_build)
    c = isub.add_parser("check", help="check a map directory: every file whole and as it was written",
                        description="Open a map as `seqnet eval --index` does (every file's size and sampled hash "
                                    "against map.json, arrays against each other) and, with --full, hash every "
                                    "byte of every file. Exit 2 naming the first file that changed.")
    c.add_argument("map", metavar="MAP", help="map directory (seqnet index build)")
    c.add_argument("--full", action="store_true", help="hash every byte (slow on a large map)")
    c.set_defaults(func=run_check)


def run_check(args: argparse.Namespace) -> int:
    from ..maps.load import check_files
    from ..maps.map import read_meta

    mp = load_map(args.map, "cpu")
    if args.full:
        check_files(mp.path, read_meta(mp.path), full=True)
    files = len(mp.meta.get("checksums") or {})
    how = "every byte hashed" if args.full else "sizes and sampled hashes"
    print(f"{mp.describe_info()}: {files} files checked ({how})" if files else
          f"{mp.describe_info()}: written before maps carried checksums; its arrays were checked against each other")
    return 0


def map_config(args: argparse.Namespace) -> MapConfig:
    """The map settings from the flags (unset flags keep the defaults)."""
    ann = drop_none({k: getattr(args, k) for k in ("kind", "nlist", "nprobe", "hnsw_m", "ef_search",
                                                   "ef_construction", "pq_m", "pq_bits", "seed")})
    return _D.merge(shortlist=args.shortlist, rerank=args.rerank, seq_len=args.seq_len,
                      match_len=args.match_len, window=args.window, ann=ann, dtype=args.dtype,
                      split=args.split, device=args.device, allow_mismatch=args.allow_mismatch or None,
                      shards=args.shards)


def run_build(args: argparse.Namespace) -> int:
    path = build(map_config(args), args.dataset, args.out, args.model,
                 {"top_k": args.top_k})
    mp = load_map(path, "cpu")
    print(mp.describe_info())
    said = coverage_line(mp.meta, args.split is not None)
    if said:
        print(said)
    print(f"{mp.nbytes / 2**20:.1f} MiB; evaluate with: {eval_command(mp.meta, path, args.dataset)}")
    return 0


def eval_command(meta: dict, path: str | Path, dataset: str | Path) -> str:
    """The ``seqnet eval --index`` command that evaluates the map as built: its window mode (a causal map refuses
    the default centred windows), and its split when the default (test) would not be it: a train or val map, or a
    map of all frames of a dataset of explicit positives (those apply to the map's own split only)."""
    conf, src = meta.get("config") or {}, meta.get("source") or {}
    argv = ["seqnet", "eval", "--index", str(path), "--dataset", str(dataset)]
    if conf.get("window", "centred") != "centred":
        argv += ["--window", str(conf["window"])]
    split = src.get("split")
    if split not in (None, "test", "all") or (split == "all" and src.get("explicit_positives")):
        argv += ["--split", str(split)]
    return shlex.join(argv)
