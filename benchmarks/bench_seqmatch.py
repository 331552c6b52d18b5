"""Benchmark whole-map SeqMatch against a bare GEMM and against a per-pair ``torch.cdist`` loop.

Three timings on the same float32, L2-normalised random descriptors (``query [Nq, D]``,
``ref [Nr, D]``):

* ``gemm``: one bare ``query @ ref.T`` (the floor: SeqMatch needs at least this GEMM);
* ``seqmatch``: :func:`seqnet.matching.seqmatch` over the whole map, ``[Nq−L+1, Nr−L+1]`` scores;
* ``cdist loop``: the original seqNet way (``aggregateMatchScores``), one ``torch.cdist`` per
  (query window, reference window) pair followed by the sum of the diagonal. Running it on all
  pairs would take many minutes, so it is timed on a random sample of pairs (in slices between the
  other timings) and EXTRAPOLATED to all pairs.

Targets: ``seqmatch / gemm <= 1.15`` and ``cdist loop / seqmatch >= 1000``.

Usage::

    python benchmarks/bench_seqmatch.py                      # defaults: Nq = Nr = 3000, D = 4096, L = 5
    python benchmarks/bench_seqmatch.py --json out.json --check
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

from seqnet.matching.seqmatch import seqmatch

GEMM_TARGET = 1.15
LOOP_TARGET = 1000.0


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--nq", type=int, default=3000, help="query frames N_q (default 3000)")
    p.add_argument("--nr", type=int, default=3000, help="reference frames N_r (default 3000)")
    p.add_argument("--dim", type=int, default=4096, help="descriptor dimension D (default 4096)")
    p.add_argument("--seq-len", type=int, default=5, help="SeqMatch length L (default 5)")
    p.add_argument("--repeats", type=int, default=7, help="timed repeats; the median is reported (default 7)")
    p.add_argument("--loop-pairs", type=int, default=3000,
                   help="random (query, reference) window pairs timed in the cdist loop (default 3000)")
    p.add_argument("--threads", type=int, default=2, help="torch intra-op threads (default 2)")
    p.add_argument("--device", default="cpu", help="torch device (default cpu)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--tile-kib", type=int, default=None,
                   help="experiment: fused tiles of this many KiB of distances "
                        "(default: the library's choice, seqnet.matching.banded.TILE_BYTES on the CPU)")
    p.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    p.add_argument("--check", action="store_true", help="exit with status 1 when a target is missed")
    return p.parse_args(argv)


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _timed(fn, device: torch.device) -> float:
    _sync(device)
    t0 = time.perf_counter()
    fn()
    _sync(device)
    return time.perf_counter() - t0


def cdist_loop(qw: torch.Tensor, rw: torch.Tensor, pairs: np.ndarray) -> torch.Tensor:
    """Per-pair SeqMatch the original seqNet way (``aggregateMatchScores`` in its test.py).

    ``qw [Na, L, D]`` / ``rw [Nb, L, D]`` are the stacked windows; for each (query window, reference
    window) pair: ``torch.cdist`` of the two ``[L, D]`` windows, the sum of the diagonal, stored into
    a score tensor.
    """
    out = -torch.ones(len(pairs), dtype=qw.dtype, device=qw.device)
    for i, (a, b) in enumerate(pairs.tolist()):
        d = torch.cdist(rw[b].unsqueeze(0), qw[a].unsqueeze(0))
        out[i] = torch.diagonal(d, 0, 1, 2).sum(-1)
    return out


def run(args: argparse.Namespace) -> dict:
    torch.set_num_threads(args.threads)
    tile = args.tile_kib * 1024 if args.tile_kib is not None else None
    device = torch.device(args.device)
    gen = torch.Generator().manual_seed(args.seed)
    q = torch.nn.functional.normalize(torch.randn(args.nq, args.dim, generator=gen), dim=1).to(device)
    r = torch.nn.functional.normalize(torch.randn(args.nr, args.dim, generator=gen), dim=1).to(device)
    L = args.seq_len
    na, nb = args.nq - L + 1, args.nr - L + 1
    qw, rw = q.unfold(0, L, 1).permute(0, 2, 1), r.unfold(0, L, 1).permute(0, 2, 1)  # [N-L+1, L, D] views

    rng = np.random.default_rng(args.seed)
    n_pairs = min(args.loop_pairs, na * nb)
    pairs = np.stack([rng.integers(0, na, n_pairs), rng.integers(0, nb, n_pairs)], axis=1)
    slices = np.array_split(np.arange(n_pairs), args.repeats)
    load_start = os.getloadavg()

    # warm-up (allocator, BLAS threads); then every repeat times the GEMM, seqmatch and one slice of
    # the sampled loop, in alternating order, so that changing machine load hits all three alike
    m = seqmatch(q, r, L, device=str(device), tile_bytes=tile, normalize=False)
    _ = q @ r.T
    cdist_loop(qw, rw, pairs[: min(50, n_pairs)])
    t_gemm, t_seq, t_loop, loop_scores = [], [], 0.0, np.empty(n_pairs)
    for i in range(args.repeats):
        steps = ["gemm", "seq", "loop"] if i % 2 == 0 else ["loop", "seq", "gemm"]
        for which in steps:
            if which == "gemm":
                t_gemm.append(_timed(lambda: q @ r.T, device))
            elif which == "seq":
                t_seq.append(_timed(lambda: seqmatch(q, r, L, device=str(device), tile_bytes=tile, normalize=False),
                                    device))
            else:
                sl = slices[i]
                t0 = time.perf_counter()
                scores = cdist_loop(qw, rw, pairs[sl])
                _sync(device)
                t_loop += time.perf_counter() - t0
                loop_scores[sl] = scores.cpu().numpy()
    gemm_s, seq_s = statistics.median(t_gemm), statistics.median(t_seq)
    paired = statistics.median(s / g for s, g in zip(t_seq, t_gemm, strict=True))
    per_pair_s = t_loop / n_pairs
    loop_all_s = per_pair_s * na * nb

    m_np = m.detach().cpu().numpy() if isinstance(m, torch.Tensor) else m
    max_err = float(np.abs(m_np[pairs[:, 0], pairs[:, 1]] - loop_scores).max())

    return {
        "config": {"nq": args.nq, "nr": args.nr, "dim": args.dim, "seq_len": L, "dtype": "float32",
                   "repeats": args.repeats, "threads": args.threads, "device": str(device),
                   "loop_pairs_sampled": int(n_pairs), "torch": torch.__version__,
                   "tile_bytes": tile,
                   "machine": platform.processor() or platform.machine(), "cpu_count": os.cpu_count()},
        "load_average_start": load_start,
        "load_average_end": os.getloadavg(),
        "gemm_s": gemm_s,
        "seqmatch_s": seq_s,
        "gemm_all_s": t_gemm,
        "seqmatch_all_s": t_seq,
        "ratio_seqmatch_vs_gemm": seq_s / gemm_s,
        "ratio_seqmatch_vs_gemm_paired_median": paired,
        "cdist_loop_per_pair_s": per_pair_s,
        "cdist_loop_sample_s": t_loop,
        "cdist_loop_extrapolated_s": loop_all_s,
        "cdist_loop_extrapolated": True,
        "ratio_loop_vs_seqmatch": loop_all_s / seq_s,
        "max_abs_diff_seqmatch_vs_loop": max_err,
        "targets": {"ratio_seqmatch_vs_gemm_max": GEMM_TARGET, "ratio_loop_vs_seqmatch_min": LOOP_TARGET},
    }


def report(res: dict) -> str:
    c = res["config"]
    na, nb = c["nq"] - c["seq_len"] + 1, c["nr"] - c["seq_len"] + 1
    ok_gemm = res["ratio_seqmatch_vs_gemm"] <= GEMM_TARGET
    ok_loop = res["ratio_loop_vs_seqmatch"] >= LOOP_TARGET
    load = "/".join(f"{x:.1f}" for x in res["load_average_start"])
    lines = [
        f"SeqMatch benchmark: Nq={c['nq']}, Nr={c['nr']}, D={c['dim']}, L={c['seq_len']}, float32, "
        f"{c['threads']} threads, {c['device']}, median of {c['repeats']} repeats "
        f"(load average {load} on {c['cpu_count']} CPUs at start)",
        f"  bare GEMM query @ ref.T      {res['gemm_s'] * 1e3:10.1f} ms",
        f"  seqmatch (whole map)         {res['seqmatch_s'] * 1e3:10.1f} ms",
        f"  cdist loop, per pair         {res['cdist_loop_per_pair_s'] * 1e6:10.1f} us "
        f"(timed on {c['loop_pairs_sampled']} random pairs: {res['cdist_loop_sample_s']:.2f} s)",
        f"  cdist loop, all {na}x{nb} pairs {res['cdist_loop_extrapolated_s']:10.1f} s  "
        "(EXTRAPOLATED from the sample, not measured)",
        f"  ratio seqmatch / GEMM        {res['ratio_seqmatch_vs_gemm']:10.3f}   "
        f"(target <= {GEMM_TARGET}: {'PASS' if ok_gemm else 'FAIL'}; "
        f"median of per-repeat ratios {res['ratio_seqmatch_vs_gemm_paired_median']:.3f})",
        f"  ratio cdist loop / seqmatch  {res['ratio_loop_vs_seqmatch']:10.0f}   "
        f"(target >= {LOOP_TARGET:.0f}: {'PASS' if ok_loop else 'FAIL'})",
        f"  max |seqmatch - loop| on the sampled pairs: {res['max_abs_diff_seqmatch_vs_loop']:.2e}",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    res = run(args)
    print(report(res))
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2) + "\n", encoding="utf-8")
    ok = res["ratio_seqmatch_vs_gemm"] <= GEMM_TARGET and res["ratio_loop_vs_seqmatch"] >= LOOP_TARGET
    return 0 if ok or not args.check else 1


if __name__ == "__main__":
    sys.exit(main())
