"""The ``seqnet benchmark timing`` stage: build each map, time it in a fresh process, report.

Synthetic maps (or the map of a user's dataset) are written to a working folder beside ``OUT``
(``.OUT.seqnet-XXXX.tmp``: deleted afterwards, and by the next run when a run was killed); ``OUT``
receives ``results.json`` (config, machine, one entry per map with its per-method rows, index build
times, peak RSS), ``results.md`` and ``timing.png``, together, replacing only an earlier timing run's.
The measuring processes import seqnet from where this one did, never from the current directory.
"""

from __future__ import annotations

import json
import os
import platform
import shutil
import subprocess
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from ...core.errors import ConfigError, ResourceError
from ...core.log import logger
from ...core.stage import Written
from ...maps import MapConfig
from ...security.dirs import recover_dir
from ...security.files import write_json_atomic, write_text_atomic
from ...security.locks import locked
from ...security.sandbox import python_command
from ...security.text import shown
from ..outputs import check_outputs_of, scratch, write_outputs
from .config import TimingConfig
from .report import markdown, plot

OUT_FILES = ("results.json", "results.md", "timing.png")
KIND = "benchmark timing"  # the command, as the output folder's record names it
LEGACY_KIND = "timing"  # the manifest kind of the outputs of seqnet versions before the record
WORKER = "import sys\nfrom seqnet.pipelines.timing.worker import main\nsys.exit(main(sys.argv[2:]))\n"


def is_timing_file(rel: str) -> bool:
    """Whether ``rel`` is a file this stage writes into its output folder."""
    return rel in OUT_FILES


def run_worker(job: dict[str, Any], tmp: Path, threads: int) -> dict[str, Any]:
    """Run one job in a fresh Python process (``threads`` BLAS / OpenMP threads) that imports seqnet from where
    this one did and never from the current directory (:func:`seqnet.security.sandbox.python_command`, started
    in ``/``); its result, or an error."""
    job_file = tmp / f"job-{job['action']}-{job['tag']}.json"
    job = {**job, "result": str(job_file.with_suffix(".result.json"))}
    job_file.write_text(json.dumps(job), encoding="utf-8")
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "MKL_NUM_THREADS": str(threads)}
    proc = subprocess.run([*python_command(WORKER), str(job_file)], env=env, cwd="/", capture_output=True,
                          text=True, check=False)
    result_file = Path(job["result"])
    res = json.loads(result_file.read_text(encoding="utf-8")) if result_file.is_file() else {}
    if "ok" not in res:
        tail = res.get("error") or (proc.stderr.strip().splitlines() or ["no output"])[-1]
        what = f"exit code {proc.returncode}" + (" (killed: out of memory?)" if proc.returncode < 0 else "")
        raise ResourceError(f"timing {job['action']} of {job['tag']} failed ({what}): {shown(tail[:300])}")
    return res["ok"]


def measure(conf: TimingConfig, out: Path, threads: int, dataset: str | Path | None, models: Sequence[str | Path],
            map_config: MapConfig | None) -> list[dict[str, Any]]:
    """Build and time every map (or the map of ``dataset``), each in fresh processes; the maps are written to a
    working folder beside ``out`` (:func:`seqnet.pipelines.outputs.scratch`), each deleted once timed."""
    entries = []
    with scratch(out) as tmp:
        targets = [(None, None)] if dataset is not None else conf.maps()
        for n, dim in targets:
            tag = "dataset" if dataset is not None else f"{n}x{dim}"
            job = {"tag": tag, "conf": conf.to_dict(), "n": n, "dim": dim, "map": str(tmp / f"map-{tag}"),
                   "queries": str(tmp / f"queries-{n}-{dim}"),
                   "dataset": str(Path(dataset).absolute()) if dataset else None,
                   "models": [str(Path(m).absolute()) for m in models],
                   "map_config": (map_config or MapConfig()).to_dict()}
            logger.info("timing: building the %s map", tag)
            built = run_worker({**job, "action": "build"}, tmp, threads)
            logger.info("timing: measuring the %s map", tag)
            entries.append({**run_worker({**job, "action": "time"}, tmp, threads), **built})
            shutil.rmtree(job["map"], ignore_errors=True)  # free the disk before the next map
    return entries


def main(conf: TimingConfig, out: str | Path, dataset: str | Path | None = None, models: Sequence[str | Path] = (),
         map_config: MapConfig | None = None, overwrite: bool = False, kind: str = KIND) -> Written:
    """Run the sweep of ``conf`` (or time the map of ``dataset`` built with ``models``); returns ``results.json``.

    ``results.json``, ``results.md`` and ``timing.png`` replace only what an earlier run of ``seqnet {kind}``
    wrote (refused before any work otherwise, unless ``overwrite``) and appear together."""
    if dataset is not None and not models and (map_config or MapConfig()).roles():
        raise ConfigError("--dataset needs the models of its map (--model S_L.pt --model S_1.pt), or a model-free "
                          "--shortlist / --rerank")
    out = Path(out)
    threads = conf.threads or torch.get_num_threads()
    with locked(out):
        check_outputs_of(out, OUT_FILES, kind, "timing results", overwrite, legacy=(LEGACY_KIND,))
        recover_dir(out)  # working folders of killed runs
        t0 = time.perf_counter()
        entries = measure(conf, out, threads, dataset, models, map_config)
        res = {"config": {**conf.to_dict(), "threads": threads, "dataset": str(dataset) if dataset else None},
               "machine": {"platform": platform.platform(), "processor": platform.processor(),
                           "cpu_count": os.cpu_count(), "torch": torch.__version__},
               "seconds": round(time.perf_counter() - t0, 1), "maps": entries}

        def write(tmp: Path) -> None:
            write_json_atomic(tmp / "results.json", res)
            write_text_atomic(tmp / "results.md", markdown(res))
            plot(res, tmp / "timing.png")

        write_outputs(out, kind, "timing results", write, overwrite, legacy=(LEGACY_KIND,))
    return Written(out / "results.json", res)
