"""One measuring process of the timing benchmark, started by :func:`seqnet.pipelines.timing.run.run_worker`
(:func:`seqnet.security.sandbox.python_command`: seqnet imported from where the parent imported it, never from
the current directory) with the path of its job file.

Each map is built in one fresh process and timed in another, so that the peak resident memory
(``ru_maxrss``) of each is its own and does not accumulate over the sweep. The job file names the
action (``build`` or ``time``), the :class:`TimingConfig`, the map and where to write the result.
"""

from __future__ import annotations

import json
import os
import resource
import sys
import time
from pathlib import Path
from typing import Any

import torch

from ...core.devices import get_device
from ...core.errors import SeqnetError
from ...maps import Map, MapConfig, build, load_map
from ...security.files import write_json_atomic
from .config import TimingConfig
from .hvpr import build_indexes, float16_recall, hvpr_rows
from .measure import describe_rows, knn_rows, seqmatch_rows
from .queries import dataset_queries, synthetic_queries
from .synth import make_map


def peak_rss() -> int:
    """Peak resident set size of this process so far, in bytes (``ru_maxrss`` is KiB on Linux)."""
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024


def build_job(job: dict[str, Any], conf: TimingConfig) -> dict[str, Any]:
    """Write the map of the job (synthetic, or from the job's dataset and models)."""
    t0 = time.perf_counter()
    if job.get("dataset"):
        mconf = MapConfig.from_dict(job["map_config"]).merge(match_len=max(conf.seq_lens), device=conf.device)
        build(mconf, job["dataset"], job["map"], job.get("models", ()))
    else:
        make_map(conf, job["n"], job["dim"], Path(job["map"]))
    return {"build_s": round(time.perf_counter() - t0, 3), "build_peak_rss_bytes": peak_rss()}


def on_device(mp: Map, dev: torch.device) -> None:
    """Copy the map's descriptors onto a GPU (streaming them from the memory map for every query would
    time the bus, not the method)."""
    if dev.type == "cuda":
        mp.frames = torch.from_numpy(mp.frames.astype("float32")).to(dev)
        mp.shortlist = torch.from_numpy(mp.shortlist.astype("float32")).to(dev)


def time_job(job: dict[str, Any], conf: TimingConfig) -> dict[str, Any]:
    """Time every method on the job's map (see :mod:`.measure`)."""
    dev = get_device(conf.device)
    mp = load_map(job["map"], str(dev))
    map_bytes = mp.nbytes
    qs = dataset_queries(conf, mp, job["dataset"]) if job.get("dataset") else \
        synthetic_queries(conf, mp, Path(job["queries"]))
    indexes, index_s = build_indexes(mp, conf)
    f16 = float16_recall(mp, qs, max(conf.seq_lens), max(conf.top_ks)) if conf.float16_recall else None
    on_device(mp, dev)
    rows = describe_rows(qs, conf, dev) + knn_rows(mp, qs, conf, dev)
    for seq_len in conf.seq_lens:
        rows += [{**r, "seq_len": seq_len} for r in seqmatch_rows(mp, qs, conf, seq_len, dev)]
        for top_k in conf.top_ks:
            rows += [{**r, "seq_len": seq_len, "top_k": top_k}
                     for r in hvpr_rows(mp, qs, conf, seq_len, top_k, indexes, dev)]
    return {"n_db": len(mp.frames), "dim": int(mp.frames.shape[1]), "items": len(mp.items), "queries": len(qs),
            "rows": rows, "index_build_s": index_s, "float16_recall@1": f16, "map_bytes": map_bytes,
            "peak_rss_bytes": peak_rss(), "threads": torch.get_num_threads(), "device": str(dev),
            "loadavg": [round(x, 2) for x in os.getloadavg()]}


ACTIONS = {"build": build_job, "time": time_job}


def main(argv: list[str]) -> int:
    """Run the job file ``argv[0]``; write ``{"ok": ...}`` or ``{"error": ...}`` to its ``result`` path."""
    job = json.loads(Path(argv[0]).read_text(encoding="utf-8"))
    try:
        out = {"ok": ACTIONS[job["action"]](job, TimingConfig.from_dict(job["conf"]))}
    except (SeqnetError, MemoryError, OSError) as e:
        out = {"error": f"{type(e).__name__}: {e}"}
    write_json_atomic(job["result"], out)
    return 0 if "ok" in out else 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
