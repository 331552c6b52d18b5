"""The SeqNet paper's tables (Garg & Milford, RA-L 2021, main paper and supplementary) as data, and the
side-by-side layout every ``seqnet experiment`` writes: the paper's rows in the paper's order, each
with the seqnet method that is that row on our data, our values, then the paper's as printed.

The values are copied as the paper prints them (bold dropped, ``-`` where it gives none); a test checks
them against the transcription in ``../shared/paper/seqnet_paper_results.md`` when it is present.
Recall cells are ``R@1/R@5/R@20``. The supplementary tables are called S1–S3 in the order the
supplementary prints them (their own numbering is not clear from the source; they are named by title).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from typing import Any

Method = str | tuple[str | None, ...] | None  # one method for every ours-column, one per column, or none


@dataclasses.dataclass(frozen=True)
class PaperRow:
    """One row of a paper table: its label, the paper's value per paper column, and the seqnet method
    (or one per ours-column, None where the row has no counterpart on our data)."""

    label: str
    values: tuple[str, ...]
    method: Method = None

    def method_for(self, column: int) -> str | None:
        """The seqnet method of ours-column ``column``."""
        return self.method[column] if isinstance(self.method, tuple) else self.method


@dataclasses.dataclass(frozen=True)
class PaperTable:
    """A table of the paper: key (``I``, ``II``, ``III``, ``S1``, ``S2``, ``S3``), title as printed, its
    columns and rows, and where the paper measured it (data, model)."""

    key: str
    title: str
    columns: tuple[str, ...]
    rows: tuple[PaperRow, ...]
    measured_on: str


def _r(label: str, method: Method, *values: str) -> PaperRow:
    return PaperRow(label, tuple(values), method)


TABLE_I = PaperTable(
    "I", "Performance Comparison - Oxford & Brisbane (Day vs Night): Recall@K", ("Oxford-FD", "Brisbane"), (
        _r("AP-GeM", None, "0.36/0.59/0.78", "0.21/0.33/0.48"),
        _r("DenseVLAD", None, "0.50/0.65/0.77", "0.33/0.43/0.54"),
        _r("NetVLAD", "single", "0.47/0.70/0.85", "0.20/0.28/0.41"),
        _r("SeqNet (S_1)", "s1", "0.47/0.69/0.86", "0.23/0.34/0.49"),
        _r("Smoothing", "smoothing", "0.59/0.72/0.85", "0.20/0.25/0.32"),
        _r("Delta", "delta-paper", "0.37/0.55/0.74", "0.20/0.33/0.50"),
        _r("SeqNet (S_5)", "seqnet", "0.62/0.76/0.88", "0.32/0.40/0.55"),
        _r("SeqMatch", "raw+seqmatch", "0.67/0.78/0.9", "0.21/0.31/0.37"),
        _r("Delta + SeqMatch", "delta-paper+seqmatch", "0.64/0.81/0.91", "0.23/0.33/0.48"),
        _r("SeqNet (S_1) + SeqMatch", "s1+seqmatch", "0.73/0.85/0.94", "0.28/0.36/0.48"),
        _r("SeqNet (S_1) + GISM", "s1+graph", "0.65/-/-", "0.26/-/-"),
        _r("SeqNet (S_1) + GRH:DH", "s1+grh-dh", "0.01/-/-", "0.09/-/-"),
        _r("SeqNet (S_1) + GRH:LSH", "s1+grh", "0.34/-/-", "0.18/-/-"),
        _r("HVPR (NetVLAD to S_1)", "hvpr-single", "0.71/0.80/0.85", "0.25/0.33/0.41"),
        _r("HVPR (Delta to S_1)", "hvpr-delta-paper", "0.65/0.72/0.74", "0.26/0.39/0.50"),
        _r("HVPR (S_5 to S_1)", "hvpr", "0.72/0.82/0.88", "0.29/0.40/0.55"),
    ), "Oxford RobotCar day/night (Brisbane-trained model) and Brisbane City Loop day/night (Oxford-trained "
       "model), NetVLAD 4096-D, L = 5")

TABLE_II = PaperTable(
    "II", "Computation Time (in ms): Mean ± Std. Dev.", ("S_1", "S_5", "SeqMatch: All", "SeqMatch: Top 20"), (
        _r("paper (GTX 1080 Ti)", None, "22.1 ± 13.0", "24.2 ± 11.9", "1449.9 ± 120.5", "1.8 ± 0.2"),
    ), "MSLS Boston, 14000 database images, D = 4096, GTX 1080 Ti; S_1 and S_5 descriptor extraction only")

TABLE_III = PaperTable(
    "III", "Reverse Traverse - Oxford-FD (Day vs Night): Recall@K", ("Vanilla SeqMatch", "Reverse SeqMatch"), (
        _r("Raw Single Descriptor", ("single", None), "0.47/0.70/0.85", "-"),
        _r("SeqNet (S_1)", ("s1", None), "0.47/0.69/0.86", "-"),
        _r("Raw + Smoothing", ("smoothing", None), "0.59/0.72/0.85", "-"),
        _r("Raw + Delta", ("delta-paper", None), "0.17/0.32/0.52", "-"),
        _r("SeqNet (S_5)", ("seqnet", None), "0.58/0.73/0.88", "-"),
        _r("Raw + SeqMatch", ("raw+seqmatch", "raw+seqmatch-rev"), "0.49/0.69/0.85", "0.67/0.78/0.90"),
        _r("SeqNet (S_1) + SeqMatch", ("s1+seqmatch", "s1+seqmatch-rev"), "0.58/0.77/0.90", "0.73/0.85/0.94"),
        _r("HVPR (S_5 to S_1)", ("hvpr", "hvpr-seqnet:s1+seqmatch-rev"), "0.59/0.78/0.87", "0.71/0.81/0.87"),
    ), "Oxford-FD day/night, database reversed, Brisbane-trained models (S_5 not trained on reverse sequences)")

TABLE_S1 = PaperTable(
    "S1", "Data Splits: Reference / Query Database Size", ("Oxford", "Brisbane", "Nordland", "MSLS"), (
        _r("Train", "train", "2981 / 2931", "12625 / 13932", "15000 / 15000", "4973 / 4474"),
        _r("Val", "val", "-", "500 / 488", "3000 / 3000", "4927 / 1732"),
        _r("Test", "test", "1574 / 1576", "2858 / 2770", "3000 / 3000", "33000 / 18000"),
    ), "the paper's four datasets")

TABLE_S2 = PaperTable(
    "S2", "Longer Sequences - Oxford-FD (Day vs Night): Recall@K", ("L_m=5", "L_m=10", "L_m=20"), (
        _r("GISM", "s1+graph", "0.65/-/-", "0.68/-/-", "0.73/-/-"),
        _r("HVPR", "hvpr", "0.72/0.82/0.88", "0.80/0.85/0.88", "0.85/0.87/0.88"),
    ), "Oxford-FD day/night, Brisbane-trained model, S_{L_d} at L_d = 5, only L_m changes")

TABLE_S3 = PaperTable(
    "S3", "Different Single Image Descriptor - Nordland (Spring vs Fall): Recall@K", ("NetVLAD", "GMP"), (
        _r("Raw Single Descriptor", "single", "0.38/0.54/0.68", "0.36/0.54/0.68"),
        _r("SeqNet (S_1)", "s1", "0.48/0.69/0.82", "0.49/0.71/0.83"),
        _r("Raw + Smoothing", "smoothing", "0.44/0.59/0.72", "0.37/0.52/0.65"),
        _r("Raw + Delta", "delta-paper", "0.56/0.70/0.80", "0.49/0.62/0.76"),
        _r("SeqNet (S_5)", "seqnet", "0.79/0.90/0.94", "0.76/0.88/0.94"),
        _r("Raw + SeqMatch", "raw+seqmatch", "0.61/0.71/0.78", "0.57/0.66/0.76"),
        _r("SeqNet (S_1) + SeqMatch", "s1+seqmatch", "0.78/0.87/0.92", "0.79/0.86/0.91"),
        _r("HVPR (S_5 to S_1)", "hvpr", "0.79/0.89/0.94", "0.82/0.90/0.94"),
    ), "full Nordland spring/fall (Summer-Winter-trained models), NetVLAD 4096-D or ResNet50 GMP 2048-D")

TABLES: dict[str, PaperTable] = {t.key: t for t in (TABLE_I, TABLE_II, TABLE_III, TABLE_S1, TABLE_S2, TABLE_S3)}
KS = (1, 5, 20)  # the paper's Recall@K


def methods_of(table: PaperTable) -> tuple[str, ...]:
    """Every seqnet method the rows of ``table`` name (in row order, once)."""
    names = (m for r in table.rows for m in (r.method if isinstance(r.method, tuple) else (r.method,)))
    return tuple(dict.fromkeys(n for n in names if n))


def recall_cell(result: Mapping[str, Any] | None, ks: Sequence[int] = KS) -> str:
    """``R@1/R@5/R@20`` of one method's results (``recall@K`` keys), 3 decimals; ``-`` where not measured."""
    if not result:
        return "–"
    return "/".join(f"{result[f'recall@{k}']:.3f}" if f"recall@{k}" in result else "-" for k in ks)


def recall_lookup(values: Sequence[Mapping[str, Mapping[str, Any]]]) -> Callable[[PaperRow, int], str]:
    """A cell function for :func:`side_by_side`: ours-column ``c`` reads ``values[c][method]``."""
    def cell(row: PaperRow, c: int) -> str:
        m = row.method_for(c)
        return recall_cell(values[c].get(m)) if m else "–"
    return cell


def side_by_side(table: PaperTable, ours: Sequence[str], cell: Callable[[PaperRow, int], str],
                 denominator: str = "positives") -> str:
    """The paper's table as Markdown with our columns first: ``| paper row | seqnet method | ours: C … |
    paper: C … |``; ``cell(row, c)`` gives ours-column ``c``; ``denominator`` (of Recall@K) is named in
    the caption."""
    header = ["paper's row", "seqnet", *(f"ours: {c}" for c in ours), *(f"paper: {c}" for c in table.columns)]
    lines = [f"**Table {table.key} — {table.title}**, beside ours. Paper: {table.measured_on}. "
             + (f"Recall@K denominator (ours): {denominator}." if "Recall" in table.title else ""), "",
             "| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    for row in table.rows:
        names = " \\| ".join(dict.fromkeys(m for c in range(len(ours)) if (m := row.method_for(c)))) or "–"
        lines.append("| " + " | ".join([row.label, f"`{names}`" if names != "–" else names,
                                        *(cell(row, c) for c in range(len(ours))), *row.values]) + " |")
    return "\n".join(lines) + "\n"
