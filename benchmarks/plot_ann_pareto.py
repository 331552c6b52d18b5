"""Pareto plot of HVPR with an approximate shortlist: R@1 against speed-up over paper-style whole-map SeqMatch.

Reads the ``results.json`` of one or more ``bench_map_distractors.py`` runs (one map size each; each
run's speed-ups are against its own whole-map figures) and draws one series per (index build, K)
over the search breadths, the Pareto front of all approximate points, horizontal lines at exact
HVPR's R@1 (smallest K of the first run) and 0.01 below it, and a vertical line at ``--goal``.

Usage::

    python benchmarks/plot_ann_pareto.py OUT/distractors-1m/results.json OUT/distractors-1m-m48/results.json \\
        --out docs/img/ann_pareto_1m.png --table
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from seqnet.report.tables import method_colours, new_figure, save_figure

MARKERS = "osD^vP*X"
LINES = ("-", "--", ":", "-.")


def build_label(args: dict) -> str:
    """The index build of a run, e.g. ``HNSW32 efC40``."""
    return f"HNSW{args['hnsw_m']} efC{args['ef_construction']}"


def load_runs(paths: list[str]) -> list[tuple[str, dict]]:
    """``(build label, result of the run's single map size)`` per results.json."""
    runs = []
    for p in paths:
        data = json.loads(Path(p).read_text())
        runs += [(build_label(data["args"]), r) for r in data["results"]]
    return runs


def approx_rows(result: dict) -> list[dict]:
    return [r for r in result["hvpr"] if r["index"] != "exact"]


def exact_recall(result: dict) -> float:
    """Exact HVPR's R@1 at the run's smallest K."""
    exact = [r for r in result["hvpr"] if r["index"] == "exact"]
    return min(exact, key=lambda r: r["top_k"])["recall@1"]


def pareto(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The points no other point beats in both speed-up and R@1, by rising speed-up (falling R@1)."""
    front, best = [], -1.0
    for x, y in sorted(points, key=lambda p: (-p[0], -p[1])):
        if y > best:
            front.append((x, y))
            best = y
    return front[::-1]


def draw_series(ax, runs: list[tuple[str, dict]]) -> None:
    """One line per (index build, K) over efSearch: colour by K, marker and line style by build."""
    ks = sorted({r["top_k"] for _, res in runs for r in approx_rows(res)})
    colours = dict(zip(ks, method_colours(len(ks)), strict=True))
    builds = list(dict.fromkeys(label for label, _ in runs))
    for label, res in runs:
        b = builds.index(label)
        for k in ks:
            rows = sorted((r for r in approx_rows(res) if r["top_k"] == k), key=lambda r: r["speedup_paper"])
            if rows:
                ax.plot([r["speedup_paper"] for r in rows], [r["recall@1"] for r in rows], color=colours[k],
                        marker=MARKERS[b % len(MARKERS)], linestyle=LINES[b % len(LINES)], markersize=4,
                        label=f"{label}, K={k}")


def draw_references(ax, runs: list[tuple[str, dict]], goal: float) -> None:
    """The Pareto front of all approximate points, exact HVPR's R@1 and 0.01 below, the speed-up goal."""
    front = pareto([(r["speedup_paper"], r["recall@1"]) for _, res in runs for r in approx_rows(res)])
    ax.step(*zip(*front, strict=True), where="pre", color="grey", alpha=0.5, linewidth=3, label="Pareto front")
    exact = exact_recall(runs[0][1])
    ax.axhline(exact, color="black", linewidth=1, label=f"exact HVPR ({exact:.3f})")
    ax.axhline(exact - 0.01, color="black", linewidth=1, linestyle="--", label="exact HVPR − 0.01")
    ax.axvline(goal, color="red", linewidth=1, linestyle=":", label=f"{goal:g}× goal")


def figure(runs: list[tuple[str, dict]], goal: float):
    from matplotlib.ticker import LogLocator, NullFormatter, ScalarFormatter

    fig, ax = new_figure(7.5, 5)
    draw_series(ax, runs)
    draw_references(ax, runs, goal)
    ax.set_xscale("log")
    ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
    ax.xaxis.set_major_formatter(ScalarFormatter())
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("speed-up per query vs paper-style whole-map SeqMatch (1 thread, log)")
    ax.set_ylabel("R@1")
    ax.set_title(f"HVPR with an HNSW shortlist at N_db = {runs[0][1]['n_db']:,} (points: efSearch)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7, loc="best", ncol=2)
    return fig


def table(runs: list[tuple[str, dict]]) -> str:
    """A Markdown table of every row: index build, efSearch, K, R@1, ms per query, speed-up, shortlist recall."""
    out = ["| index | efSearch | K | R@1 | ms / query | speed-up vs paper-style | shortlist recall |",
           "|---|---|---|---|---|---|---|"]
    for label, res in runs:
        for r in res["hvpr"]:
            name = f"exact ({label} run)" if r["index"] == "exact" else label
            out.append(f"| {name} | {r.get('ef_search', '–')} | {r['top_k']} | {r['recall@1']:.3f} | "
                       f"{r['ms'][0]:.2f} ± {r['ms'][1]:.2f} | {r['speedup_paper']:g}× | "
                       f"{r.get('shortlist_recall', '–')} |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("results", nargs="+", help="results.json files of bench_map_distractors.py")
    p.add_argument("--out", required=True, help="PNG to write")
    p.add_argument("--goal", type=float, default=50.0, help="speed-up goal drawn as a vertical line (default 50)")
    p.add_argument("--table", action="store_true", help="also print a Markdown table of every row")
    args = p.parse_args(argv)
    runs = load_runs(args.results)
    save_figure(figure(runs, args.goal), args.out)
    if args.table:
        print(table(runs))


if __name__ == "__main__":
    main()
