"""How each method is drawn in a figure: its family gives the colour's hue, its place in the family the shade,
the line style and the marker, so that 25 methods on one plot stay told apart.

Families (:func:`method_family`): k-NN on a single-image descriptor, k-NN on a sequence descriptor, each
whole-map matcher (SeqMatch, velocity SeqMatch, graph, GRH; the ``-rev`` variants with their matcher), HVPR,
and ``other`` for a name that is not a method (a given distance matrix). :func:`method_styles` gives every
method a ``(colour, line style, marker)`` no other method of the figure has; :func:`grouped` orders the
methods by family for a legend.
"""

from __future__ import annotations

import colorsys
from collections.abc import Sequence
from typing import Any

from ..core.errors import ConfigError
from ..methods.grammar import parse_method

# family: (its order in a legend, its hue as an RGB colour of matplotlib's tab10)
FAMILIES: dict[str, tuple[float, float, float]] = {
    "k-NN, single image": (0.122, 0.467, 0.706),  # blue
    "k-NN, sequence descriptor": (0.090, 0.745, 0.812),  # cyan
    "SeqMatch": (0.173, 0.627, 0.173),  # green
    "velocity SeqMatch": (0.737, 0.741, 0.133),  # olive
    "graph": (0.580, 0.404, 0.741),  # purple
    "GRH": (0.549, 0.337, 0.294),  # brown
    "HVPR": (0.839, 0.153, 0.157),  # red
    "other whole-map matcher": (0.890, 0.467, 0.761),  # pink
    "other": (0.498, 0.498, 0.498),  # grey
}
# the ground truth in the distance matrix: tab10's orange, the one hue no family has
TRUTH_COLOUR = (1.0, 0.498, 0.055)
MATCHER_FAMILIES = {"seqmatch": "SeqMatch", "vseqmatch": "velocity SeqMatch", "graph": "graph", "grh": "GRH",
                    "grh-dh": "GRH"}
LINE_STYLES = ("-", "--", ":", "-.")
MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*", "<", ">")


def method_family(name: str) -> str:
    """The family of a method name (a key of :data:`FAMILIES`)."""
    try:
        m = parse_method(name)
    except ConfigError:
        return "other"
    if m.kind == "hvpr":
        return "HVPR"
    if m.kind == "knn":
        return "k-NN, single image" if m.single_frame else "k-NN, sequence descriptor"
    base = (m.matcher or "").removesuffix("-rev")
    return MATCHER_FAMILIES.get(base, "other whole-map matcher")


def grouped(names: Sequence[str]) -> list[tuple[str, list[str]]]:
    """``[(family, its methods in the order given)]``, families in the order of :data:`FAMILIES`."""
    groups: dict[str, list[str]] = {}
    for n in names:
        groups.setdefault(method_family(n), []).append(n)
    return sorted(groups.items(), key=lambda g: list(FAMILIES).index(g[0]))


def shade(rgb: tuple[float, float, float], i: int, n: int) -> tuple[float, float, float]:
    """The ``i``-th of ``n`` shades of ``rgb``: lightness from dark to light around the hue's own, saturation kept."""
    h, lightness, s = colorsys.rgb_to_hls(*rgb)
    if n > 1:
        lightness = 0.28 + 0.42 * i / (n - 1)  # 0.28 (dark) .. 0.70 (light): each still reads on white
    return colorsys.hls_to_rgb(h, lightness, s)


def method_styles(names: Sequence[str]) -> dict[str, dict[str, Any]]:
    """``{name: {"color", "linestyle", "marker"}}``: the family's hue in a shade of its own for each member (up to
    a family of any size), with a line style and a marker of its own: no two methods share the three."""
    out: dict[str, dict[str, Any]] = {}
    for family, members in grouped(names):
        for i, name in enumerate(members):
            out[name] = {"color": shade(FAMILIES[family], i, len(members)),
                         "linestyle": LINE_STYLES[i % len(LINE_STYLES)], "marker": MARKERS[i % len(MARKERS)]}
    return out


def family_legend(ax: Any, names: Sequence[str], labels: dict[str, str] | None = None, fontsize: float = 7,
                  first: Sequence[str] = ()) -> Any:
    """A legend beside the axes (never over a curve), grouped by family: a bold family heading, then its methods
    (``labels``: the text of each, default its name), after the artists labelled ``first`` (not methods: the
    ground truth); two columns past 30 rows."""
    from matplotlib.lines import Line2D

    handles = {h.get_label(): h for h in ax.get_lines() + list(ax.collections)}
    entries, texts, heads = [handles[n] for n in first], list(first), []
    for family, members in grouped([n for n in names if n in handles]):
        heads.append(len(entries))
        entries.append(Line2D([], [], linestyle="none"))
        texts.append(family)
        for n in members:
            entries.append(handles[n])
            texts.append((labels or {}).get(n, n))
    leg = ax.legend(entries, texts, fontsize=fontsize, loc="upper left", bbox_to_anchor=(1.02, 1.0),
                    borderaxespad=0, ncol=1 if len(entries) <= 30 else 2, handlelength=3.2, frameon=False)
    for i in heads:
        leg.get_texts()[i].set_fontweight("bold")
    return leg
