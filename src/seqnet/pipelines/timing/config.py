"""Settings of ``seqnet benchmark timing`` (defaults: a small sweep that runs in minutes on 2 CPU cores)."""

from __future__ import annotations

import dataclasses

from ...core.config import Config, check_bool, check_choice, check_float, check_int, check_ints
from ...core.devices import check_device
from ...core.errors import ConfigError
from ...maps.config import DTYPES
from ...search.ann import ANN_INDEXES, AnnConfig

BIG_SIZES = (1000, 14000, 100000, 1000000)  # --big: up to 1M at D = 256, 100k at D = 4096 (max_elements)


@dataclasses.dataclass(frozen=True)
class TimingConfig(Config):
    """What is timed, on which maps.

    Attributes:
        sizes: N_db, reference frames of each synthetic map; dims: D of each (every size × dim pair
            with ``N_db·D <= max_elements`` is measured).
        seq_len: L of the S_L shortlist descriptor (w = ``sl_w``); seq_lens: the L_m swept;
            top_ks: the shortlist sizes K swept.
        queries: queries timed one at a time (mean ± std) and in one batch (throughput).
        repeats: batch runs (the median is reported); warmup: untimed queries first.
        indexes: ANN index kinds timed as HVPR shortlisters (exact search is always timed); ann:
            their settings (``kind`` ignored).
        device: torch device (cpu default; a GPU when asked and present: the map is then copied onto it).
        dtype: storage of the map's descriptors; float16_recall: also report R@1 with the map rounded
            to float16.
        noise: query noise of the synthetic maps (per-frame Gaussian, relative to a unit descriptor).
        threads: torch / BLAS threads of the measuring processes (None: the current torch setting).
        seed: random seed of the synthetic maps.
    """

    sizes: tuple[int, ...] = (1000, 14000)
    dims: tuple[int, ...] = (256, 4096)
    max_elements: int = 410_000_000
    seq_len: int = 5
    sl_w: int = 3
    seq_lens: tuple[int, ...] = (5,)
    top_ks: tuple[int, ...] = (20,)
    queries: int = 50
    repeats: int = 3
    warmup: int = 3
    indexes: tuple[str, ...] = ("hnsw", "ivf-flat", "ivf-pq")
    ann: AnnConfig = AnnConfig(nprobe=16, ef_search=128)
    device: str = "cpu"
    dtype: str = "float32"
    float16_recall: bool = True
    noise: float = 1.0
    threads: int | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        self._set("sizes", check_ints("sizes", self.sizes, 100))
        self._set("dims", check_ints("dims", self.dims, 8))
        self._set("max_elements", check_int("max_elements", self.max_elements, 1))
        self._set("seq_len", check_int("seq_len", self.seq_len, 1))
        self._set("sl_w", check_int("sl_w", self.sl_w, 1, self.seq_len))
        self._set("seq_lens", check_ints("seq_lens", self.seq_lens, 1))
        self._set("top_ks", check_ints("top_ks", self.top_ks, 1))
        for key, low in (("queries", 1), ("repeats", 1), ("warmup", 0), ("seed", 0)):
            self._set(key, check_int(key, getattr(self, key), low))
        # aliases only: --indexes is a comma-separated list (a factory string has commas of its own)
        self._set("indexes", tuple(check_choice("ANN index kind", k, ANN_INDEXES) for k in self.indexes))
        if not isinstance(self.ann, AnnConfig):
            raise ConfigError(f"ann must be an AnnConfig, got {type(self.ann).__name__}")
        check_device(self.device)
        check_choice("map dtype", self.dtype, DTYPES)
        self._set("float16_recall", check_bool("float16_recall", self.float16_recall))
        self._set("noise", check_float("noise", self.noise, 0.0))
        if self.threads is not None:
            self._set("threads", check_int("threads", self.threads, 1))
        if not self.maps():
            raise ConfigError(f"no size × dim pair has N_db·D <= max_elements={self.max_elements}")

    def maps(self) -> list[tuple[int, int]]:
        """The ``(N_db, D)`` pairs measured, smallest first."""
        return sorted((n, d) for n in self.sizes for d in self.dims if n * d <= self.max_elements)

    @property
    def window(self) -> int:
        """Frames each query item needs: the longest of L and the L_m swept."""
        return max(self.seq_len, *self.seq_lens)
