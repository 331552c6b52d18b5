"""``seqnet experiment tsne`` (the paper's t-SNE figure): 2-D t-SNE embeddings of the descriptors of
the first ``frames`` summer (reference) frames of the **test** split — as the paper, "the first 1000
images of the Nordland Summer test set": never the frames the models were trained on — raw
single-image, smoothing, Delta (the paper's, ``delta-paper``), S_1 and S_L (S_5), coloured by
position along the route. Window descriptors are clamped at the test split's ends.

A descriptor that follows the route draws a continuous curve; one that confuses places scatters
them. The same property as a number: the *route-neighbour rate*, the fraction of each frame's
``k`` nearest descriptors (itself excluded) that lie within ``span`` places of it along the route,
measured in descriptor space and in the embedding. Needs scikit-learn (``pip install
scikit-learn``, or the ``experiments`` extra), imported only here.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...core.config import Config, check_choice, check_float, check_int
from ...core.errors import ResourceError
from ...search.knn import knn
from ...sequence.descriptors import SEQUENCE_DESCRIPTORS, describe_windows
from ...sequence.windows import window_indices
from ..nordland64 import Nordland64Config
from .common import Outputs, check_experiment, locked_dirs, markdown_table, prepare, table_section, write_outputs

if TYPE_CHECKING:
    from ...sequence.model import SeqNet


DESCRIPTORS = {"raw": "single", "smoothing": "smoothing", "delta": "delta-paper", "S_1": "s1", "S_L": "seqnet"}
SPLIT = "test"  # the paper's: the first images of the Summer test set


@dataclasses.dataclass(frozen=True)
class TsneConfig(Config):
    """Settings of the t-SNE experiment.

    Attributes:
        benchmark: the benchmark's settings (descriptors, models; L of the window descriptors).
        frames: the first ``frames`` summer frames of the test split are embedded (all of it when shorter).
        descriptors: keys of :data:`DESCRIPTORS` (raw, smoothing, delta, S_1, S_L).
        perplexity, seed: t-SNE settings; pca_dims: PCA before t-SNE (0: none).
        k, span: route-neighbour rate: of the k nearest descriptors, those within ``span`` places.
    """

    benchmark: Nordland64Config = Nordland64Config()
    frames: int = 1000
    descriptors: tuple[str, ...] = tuple(DESCRIPTORS)
    perplexity: float = 30.0
    pca_dims: int = 50
    seed: int = 0
    k: int = 10
    span: int = 10

    def __post_init__(self) -> None:
        self._set("frames", check_int("frames", self.frames, 10))
        self._set("descriptors", tuple(check_choice("t-SNE descriptor", d, DESCRIPTORS) for d in self.descriptors))
        self._set("perplexity", check_float("perplexity", self.perplexity, 1.0))
        for key, low in (("pca_dims", 0), ("seed", 0), ("k", 1), ("span", 0)):
            self._set(key, check_int(key, getattr(self, key), low))


def sklearn_manifold() -> Any:
    """``sklearn.manifold`` (ResourceError with the install hint when scikit-learn is missing)."""
    try:
        import sklearn.manifold
    except ImportError as err:
        raise ResourceError("the tsne experiment needs scikit-learn: pip install scikit-learn "
                            "(or pip install 'seqnet[experiments]')") from err
    return sklearn.manifold


def frame_descriptors(desc: np.ndarray, name: str, seq_len: int, models: dict[str, SeqNet]) -> np.ndarray:
    """``[N, D']`` descriptor ``name`` (a :data:`DESCRIPTORS` key) of every frame of ``desc [N, D]``
    (window descriptors over each frame's centred window, clamped at the ends)."""
    d = SEQUENCE_DESCRIPTORS[DESCRIPTORS[name]]
    idx = window_indices(len(desc), d.length(seq_len), "centred")
    return describe_windows(np.asarray(desc, np.float32), idx, d.window_fn(models)).numpy()


def route_neighbour_rate(x: np.ndarray, k: int, span: int) -> float:
    """Fraction of each row's ``k`` nearest rows (L2, itself excluded) within ``span`` rows of it."""
    _, idx = knn(x.astype(np.float32), x.astype(np.float32), k + 1, device="cpu")
    rows = np.arange(len(x))[:, None]
    others = np.array([r[r != i][:k] for i, r in enumerate(idx)])  # drop the frame itself
    return float((np.abs(others - rows) <= span).mean())


def embed(x: np.ndarray, conf: TsneConfig) -> np.ndarray:
    """The 2-D t-SNE embedding ``[N, 2]`` of ``x [N, D]`` (after a PCA to ``conf.pca_dims``)."""
    manifold = sklearn_manifold()
    from sklearn.decomposition import PCA

    if conf.pca_dims and x.shape[1] > conf.pca_dims:
        x = PCA(conf.pca_dims, random_state=conf.seed).fit_transform(x)
    tsne = manifold.TSNE(2, perplexity=min(conf.perplexity, (len(x) - 1) / 3), init="pca", random_state=conf.seed)
    return tsne.fit_transform(x)


def main(conf: TsneConfig, data: str | Path, out: str | Path, cache: str | Path | None = None,
         overwrite: bool = False) -> Path:
    """Run the experiment; writes ``results.json``, ``results.md``, ``tsne.png``, ``report.html`` and
    ``config.json`` to ``out``."""
    sklearn_manifold()  # before any work
    out = Path(out)
    cache = Path(cache) if cache else out
    with locked_dirs(out, cache):
        check_experiment(out, "tsne", overwrite)
        p = prepare(conf.benchmark, data, cache, overwrite=overwrite)
        ref, first = p.ds.split(SPLIT).reference, p.ds.ranges(SPLIT)["reference"][0]
        n = min(conf.frames, len(ref))
        emb, rows = {}, []
        for name in conf.descriptors:
            x = frame_descriptors(ref.descriptors[:n], name, conf.benchmark.seq_len, p.models)
            emb[name] = embed(x, conf)
            rows.append([name, x.shape[1], route_neighbour_rate(x, conf.k, conf.span),
                         route_neighbour_rate(emb[name], conf.k, conf.span)])
        header = ["descriptor", "D", f"route neighbours ({conf.k}-NN within ±{conf.span} places)", "same in t-SNE"]
        results = {"experiment": "tsne", "frames": n, "split": SPLIT, "frame_range": [int(first), int(first + n)],
                   "first_place": p.ds.extra.get("first_place", 0),
                   "route_neighbour_rate": {r[0]: {"descriptor": r[2], "tsne": r[3]} for r in rows},
                   "dims": {r[0]: r[1] for r in rows}, "timings_s": p.seconds, "provenance": ref.provenance}
        md = (f"# t-SNE of the first {n} summer frames of the test split (frames {first}:{first + n})\n\n"
              f"L = {conf.benchmark.seq_len} for the window descriptors; "
              f"perplexity {conf.perplexity:g}, PCA {conf.pca_dims} first, seed {conf.seed}.\n\n"
              + markdown_table(header, rows))
        o = Outputs("tsne", results, md, tsne_figure(emb, ref.positions[:n, 0]),
                    [table_section("experiment", "t-SNE", {"Route-neighbour rate": (header, rows)},
                                   f"The first {n} summer frames of the test split, coloured by position along "
                                   "the route.")])
        return write_outputs(o, conf, data, out, f"Experiment: t-SNE of the first {n} summer test frames", overwrite)


def tsne_figure(emb: dict[str, np.ndarray], pos: np.ndarray) -> object:
    """One t-SNE scatter per descriptor, coloured by position along the route."""
    from ...report.tables import new_figure

    fig, axes = new_figure(3.2 * len(emb), 3.6, ncols=len(emb))
    axes = np.atleast_1d(axes)
    for ax, (name, e) in zip(axes, emb.items(), strict=True):
        sc = ax.scatter(e[:, 0], e[:, 1], c=pos, cmap="viridis", s=3, linewidths=0)
        ax.set_title(name)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(sc, ax=axes[-1], fraction=0.08, label="position along the route (frame / 10)")
    return fig
