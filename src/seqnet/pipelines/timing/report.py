"""The timing report: per-map tables, the paper's compute-time table side by side, the log-log plot."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from ...report.paper import TABLE_II
from ...report.tables import new_figure, save_figure

PLOTTED = ("knn_single", "seqmatch_all_paper", "seqmatch_all_ours", "seqmatch_topk", "hvpr_exact", "hvpr_hnsw",
           "hvpr_ivf-flat", "hvpr_ivf-pq")


def _ms(x: float | None) -> str:
    return "–" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.2f}"


def _row(rows: list[dict[str, Any]], method: str, seq_len: int | None = None, top_k: int | None = None) -> dict:
    for r in rows:
        if r["method"] == method and seq_len in (None, r.get("seq_len")) and top_k in (None, r.get("top_k")):
            return r
    return {}


def map_table(e: dict[str, Any]) -> str:
    """One Markdown table of a map's rows."""
    head = ("| method | L_m | K | per query ms (mean ± std) | CPU ms / query | batch ms / query | comparisons / query "
            "| R@1 | shortlist recall@K |\n|---|---|---|---|---|---|---|---|---|")
    lines = [head]
    for r in e["rows"]:
        pq = f"{r['per_query_ms']:.2f} ± {r['per_query_std_ms']:.2f}"
        lines.append(f"| {r['method']} | {r.get('seq_len', '–')} | {r.get('top_k', '–')} | {pq} | "
                     f"{_ms(r.get('per_query_cpu_ms'))} | {_ms(r.get('batch_ms_per_query'))} | {r['comparisons']:,} | "
                     f"{r.get('recall@1', '–')} | {r.get('shortlist_recall', '–')} |")
    return "\n".join(lines)


# what each column of the paper's Table II is here: measured the paper's way (S_1 / S_5 extraction only, SeqMatch
# per query with nothing reused) and end to end (a descriptor and its k-NN; whole-map SeqMatch reusing its rows)
PAPER_WAY = {"S_1": ("describe_s1",), "S_5": ("describe_sl",), "SeqMatch: All": ("seqmatch_all_paper",),
             "SeqMatch: Top 20": ("seqmatch_topk",)}
END_TO_END = {"S_1": ("describe_s1", "knn_single"), "S_5": ("describe_sl", "knn_shortlist"),
              "SeqMatch: All": ("seqmatch_all_ours",), "SeqMatch: Top 20": ("seqmatch_topk",)}


def table_ii(e: dict[str, Any], seq_len: int, top_k: int) -> dict[str, dict[str, tuple[float, float] | None]]:
    """``{"paper's way" | "end to end": {column: (mean, std) ms}}`` of the paper's Table II columns on one
    map (a sum of parts: means added, variances added); None where a part was not measured."""
    def total(methods: tuple[str, ...]) -> tuple[float, float] | None:
        found = [_row(e["rows"], m, seq_len if m.startswith(("seqmatch", "hvpr")) else None,
                      top_k if m.startswith(("seqmatch_topk", "hvpr")) else None) for m in methods]
        if not all(found):
            return None
        return sum(f["per_query_ms"] for f in found), math.sqrt(sum(f["per_query_std_ms"] ** 2 for f in found))

    return {name: {col: total(parts[col]) for col in TABLE_II.columns}
            for name, parts in (("paper's way", PAPER_WAY), ("end to end", END_TO_END))}


def paper_table(e: dict[str, Any], seq_len: int, top_k: int) -> str:
    """The paper's Table II in its layout (columns S_1, S_5, SeqMatch: All, SeqMatch: Top 20), the paper's
    row first, then ours measured the paper's way and end to end (ms per query, mean ± std)."""
    ours = table_ii(e, seq_len, top_k)
    cols = TABLE_II.columns
    lines = [f"**Table II — {TABLE_II.title}**, beside ours (paper: {TABLE_II.measured_on}; ours: N_db = "
             f"{e['n_db']:,}, D = {e['dim']}, L_m = {seq_len}, top {top_k}).", "",
             "| | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols),
             "| " + " | ".join([TABLE_II.rows[0].label, *TABLE_II.rows[0].values]) + " |"]
    for name, row in ours.items():
        cells = ["–" if v is None else f"{v[0]:.2f} ± {v[1]:.2f}" for v in row.values()]
        lines.append(f"| ours, {name} | " + " | ".join(cells) + " |")
    lines.append("\nThe paper's way: S_1 / S_5 are descriptor extraction only and SeqMatch scores L_m distance rows "
                 "per query with nothing reused; end to end: S_1 / S_5 include their k-NN over the map, and "
                 "SeqMatch: All reuses each frame's distance row (OnlineSeqMatch).")
    hv = ", ".join(f"{r['method']} {r['per_query_ms']:.2f}" for r in e["rows"]
                   if r["method"].startswith("hvpr_") and r.get("seq_len") == seq_len and r.get("top_k") == top_k)
    return "\n".join(lines) + f"\n\nHVPR end to end (S_L + S_1 + shortlist + re-rank), ms per query: {hv}\n"


def markdown(res: dict[str, Any]) -> str:
    """``results.md``: per-map tables, peak RSS, and the paper table for each map."""
    c = res["config"]
    out = ["# seqnet benchmark timing", "", f"{res['machine']['platform']}, {c['threads']} threads, device "
           f"{c['device']}, {c['queries']} queries per figure; {res['seconds']:.0f} s in all.", ""]
    for e in res["maps"]:
        out += [f"## N_db = {e['n_db']:,}, D = {e['dim']} ({e['items']:,} items)", "",
                f"Map {e['map_bytes'] / 2**20:.1f} MiB; peak RSS timing {e['peak_rss_bytes'] / 2**20:.0f} MiB, "
                f"build {e['build_peak_rss_bytes'] / 2**20:.0f} MiB; index build s {e['index_build_s']}; load "
                f"average {e['loadavg']}; float16 map R@1 (HVPR exact): {e['float16_recall@1']}.", "",
                map_table(e), "", paper_table(e, c["seq_lens"][-1], c["top_ks"][-1]), ""]
    return "\n".join(out)


def plot(res: dict[str, Any], path: str | Path) -> Path:
    """Log-log per-query CPU time against N_db (robust to other processes sharing the cores), one line per
    method, one panel per D."""
    dims = sorted({e["dim"] for e in res["maps"]})
    fig, axes = new_figure(5.5 * len(dims), 4.2, ncols=len(dims))
    axes = axes if len(dims) > 1 else [axes]
    seq_len, top_k = res["config"]["seq_lens"][-1], res["config"]["top_ks"][-1]
    for ax, dim in zip(axes, dims, strict=True):
        maps = sorted((e for e in res["maps"] if e["dim"] == dim), key=lambda e: e["n_db"])
        for method in PLOTTED:
            pts = [(e["n_db"], r.get("per_query_cpu_ms", r["per_query_ms"])) for e in maps
                   if (r := _row(e["rows"], method, seq_len if method.startswith(("seq", "hvpr")) else None,
                                 top_k if method.startswith(("seqmatch_topk", "hvpr")) else None))]
            if pts:
                ax.plot(*zip(*pts, strict=True), marker="o", label=method)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("N_db (reference frames)")
        ax.set_ylabel("process CPU ms per query (one at a time)")
        ax.set_title(f"D = {dim}, L_m = {seq_len}, K = {top_k}")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    return save_figure(fig, path)
