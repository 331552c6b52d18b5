"""The ``seqnet benchmark timing`` stage: build each map, time it in a fresh process, report.

Synthetic maps (or the map of a user's dataset) are written to a temporary directory that is
deleted afterwards; ``OUT`` receives ``results.json`` (config, machine, one entry per map with its
per-method rows, index build times, peak RSS), ``results.md`` and ``timing.png``.
"""

from __future__ import annotations

import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from ...core.errors import ConfigError, ResourceError
from ...core.stage import Written
from ...core.utils import logger
from ...maps import MapConfig
from ...security.files import write_json_atomic, write_text_atomic
from ...security.locks import locked
from ...security.ownership import check_replaceable, write_manifest
from .config import TimingConfig
from .report import markdown, plot

OUT_FILES = ("results.json", "results.md", "timing.png")
PACKAGE_ROOT = Path(__file__).resolve().parents[3]  # the folder holding the seqnet package


def is_timing_file(rel: str) -> bool:
    """Whether ``rel`` is a file this stage writes into its output folder."""
    return rel in OUT_FILES


def run_worker(job: dict[str, Any], tmp: Path, threads: int) -> dict[str, Any]:
    """Run one job in a fresh Python process (``threads`` BLAS / OpenMP threads); its result, or an error."""
    job_file = tmp / f"job-{job['action']}-{job['tag']}.json"
    job = {**job, "result": str(job_file.with_suffix(".result.json"))}
    job_file.write_text(json.dumps(job), encoding="utf-8")
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "MKL_NUM_THREADS": str(threads),
           "PYTHONPATH": os.pathsep.join([str(PACKAGE_ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    proc = subprocess.run([sys.executable, "-m", "seqnet.pipelines.timing.worker", str(job_file)], env=env,
                          capture_output=True, text=True, check=False)
    result_file = Path(job["result"])
    res = json.loads(result_file.read_text(encoding="utf-8")) if result_file.is_file() else {}
    if "ok" not in res:
        tail = res.get("error") or (proc.stderr.strip().splitlines() or ["no output"])[-1]
        what = f"exit code {proc.returncode}" + (" (killed: out of memory?)" if proc.returncode < 0 else "")
        raise ResourceError(f"timing {job['action']} of {job['tag']} failed ({what}): {tail[:300]}")
    return res["ok"]


def main(conf: TimingConfig, out: str | Path, dataset: str | Path | None = None, models: Sequence[str | Path] = (),
         map_config: MapConfig | None = None) -> Written:
    """Run the sweep of ``conf`` (or time the map of ``dataset`` built with ``models``); returns ``results.json``."""
    if dataset is not None and not models and (map_config or MapConfig()).roles():
        raise ConfigError("--dataset needs the models of its map (--model S_L.pt --model S_1.pt), or a model-free "
                          "--shortlist / --rerank")
    out = Path(out)
    threads = conf.threads or torch.get_num_threads()
    with locked(out):
        check_replaceable(out, "timing results", is_timing_file)
        out.mkdir(parents=True, exist_ok=True)
        t0, entries = time.perf_counter(), []
        with tempfile.TemporaryDirectory(prefix="seqnet-timing-") as tmp:
            targets = [(None, None)] if dataset is not None else conf.maps()
            for n, dim in targets:
                tag = "dataset" if dataset is not None else f"{n}x{dim}"
                job = {"tag": tag, "conf": conf.to_dict(), "n": n, "dim": dim, "map": str(Path(tmp) / f"map-{tag}"),
                       "queries": str(Path(tmp) / f"queries-{n}-{dim}"), "dataset": str(dataset) if dataset else None,
                       "models": [str(m) for m in models], "map_config": (map_config or MapConfig()).to_dict()}
                logger.info("timing: building the %s map", tag)
                built = run_worker({**job, "action": "build"}, Path(tmp), threads)
                logger.info("timing: measuring the %s map", tag)
                entries.append({**run_worker({**job, "action": "time"}, Path(tmp), threads), **built})
                shutil.rmtree(job["map"], ignore_errors=True)  # free the disk before the next map
        res = {"config": {**conf.to_dict(), "threads": threads, "dataset": str(dataset) if dataset else None},
               "machine": {"platform": platform.platform(), "processor": platform.processor(),
                           "cpu_count": os.cpu_count(), "torch": torch.__version__},
               "seconds": round(time.perf_counter() - t0, 1), "maps": entries}
        path = Written(write_json_atomic(out / "results.json", res), res)
        write_text_atomic(out / "results.md", markdown(res))
        plot(res, out / "timing.png")
        write_manifest(out, "timing", [out / f for f in OUT_FILES])
    return path
