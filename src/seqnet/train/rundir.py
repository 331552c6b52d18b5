"""A run directory's files: which are seqnet's, and what a new run or ``--resume`` does with a run that stopped.

Ownership: before anything else a run writes ``RUN/.seqnet-manifest.json`` (kind ``train-run``,
:mod:`seqnet.security.ownership`) listing the files it writes (``config.json``, ``best.pt``, ``last.pt``)
and, once opened, each TensorBoard events file; events files also carry seqnet's mark in their name
(``events.out.tfevents.*.seqnet``), so one opened just before a kill is still recognised. Temporary files of
the atomic writes carry the mark of :func:`seqnet.security.files.temp_prefix`. Only names seqnet writes
count as listed (a manifest listing ``thesis.tex`` does not make it seqnet's).

A stopped run is in one of two states: ``last.pt`` present, resumable (``--resume``); or no ``last.pt``
(killed, or out of space, before its first epoch was saved): nothing to resume, so the same command,
or ``--resume`` with the stored ``config.json``, starts it again, removing only seqnet's files and saying
which. A directory holding anything else, or links where the run's files belong, is refused, never emptied.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from ..core.errors import CheckpointError, ConfigError, OutputError
from ..core.log import logger
from ..security.files import TEMP_SUFFIX, temp_prefix
from ..security.jsonfile import read_json_object
from ..security.ownership import MANIFEST, read_manifest, write_manifest

RUN_KIND = "train-run"
RUN_NAMES = ("config.json", "best.pt", "last.pt")
EVENTS_PREFIX, EVENTS_MARK = "events.out.tfevents.", ".seqnet"  # EVENTS_MARK: the events files' name suffix
CONFIG_BYTES = 1 << 20
RESTART = "restart"  # the key of what :func:`restart_payload` returns: the files a restart discards


def is_events(name: str) -> bool:
    """Whether ``name`` is a TensorBoard events file name seqnet gives (its mark at the end)."""
    return name.startswith(EVENTS_PREFIX) and name.endswith(EVENTS_MARK) and "/" not in name


def _listed(out_dir: Path) -> set[str] | None:
    """The run files the manifest of ``out_dir`` lists (None: no run manifest, or a link in its place)."""
    if (out_dir / MANIFEST).is_symlink():
        return None
    data = read_manifest(out_dir)
    if data is None or data.get("kind") != RUN_KIND:
        return None
    return {f for f in data["files"] if isinstance(f, str) and (f in RUN_NAMES or
                                                               (f.startswith(EVENTS_PREFIX) and "/" not in f))}


def _marked_temp(name: str) -> bool:
    return name.endswith(TEMP_SUFFIX) and any(name.startswith(temp_prefix(n)) for n in (*RUN_NAMES, MANIFEST))


def survey(out_dir: Path) -> tuple[list[Path], list[str]]:
    """``(seqnet's files, the other names)`` in the run directory ``out_dir``: seqnet's are regular files
    (never links) that its run manifest lists, its marked events files, the manifest itself, and the
    marked temporary files of atomic writes (by their mark alone)."""
    listed = _listed(out_dir)
    ours: list[Path] = []
    other: list[str] = []
    for p in sorted(out_dir.iterdir()):
        n = p.name
        regular = p.is_file() and not p.is_symlink()
        by_manifest = listed is not None and (n == MANIFEST or n in listed or is_events(n))
        if regular and (by_manifest or _marked_temp(n)):
            ours.append(p)
        else:
            other.append(n + ("/" if p.is_dir() and not p.is_symlink() else ""))
    return ours, other


def check_links(out_dir: Path) -> None:
    """Refuse a run directory with a symbolic link where a run file or the manifest belongs: seqnet neither
    reads one as its own nor writes over it."""
    for n in (*RUN_NAMES, MANIFEST):
        if (out_dir / n).is_symlink():
            raise OutputError(f"{out_dir / n} is a symbolic link, not the file a seqnet run writes; seqnet does not "
                              "read or replace a run's files through links (hint: remove the link)")


def check_new(out_dir: Path) -> None:
    """A new run needs ``out_dir`` absent or empty, or holding only a run of seqnet's that stopped before its
    first epoch was saved, which it starts again (:func:`discard`); anything else is refused."""
    if out_dir.exists() and not out_dir.is_dir():
        raise ConfigError(f"run directory {out_dir} is a file (hint: another --out)")
    if not out_dir.exists() or not any(out_dir.iterdir()):
        return
    if (out_dir / "last.pt").exists() or (out_dir / "last.pt").is_symlink():
        raise ConfigError(f"run directory {out_dir} is not empty: it holds a run (last.pt) (hint: another --out, "
                          f"or --resume {out_dir} to continue it)")
    ours, other = survey(out_dir)
    if other:
        more = f" and {len(other) - 1} more" if len(other) > 1 else ""
        raise ConfigError(f"run directory {out_dir} is not empty: it holds {other[0]}{more}, which no seqnet run "
                          "recorded writing there (hint: another --out, or move those files away)")
    discard(out_dir, ours, "starting a new run in its place", keep_config=False)


def discard(out_dir: Path, ours: list[Path], how: str, keep_config: bool = True) -> None:
    """Remove what a run that stopped before its first epoch was saved left (seqnet's files only, ``ours``),
    with one INFO line naming it. The manifest stays (it is rewritten atomically), and with ``keep_config``
    ``config.json`` too: the same run starts again, and under torchrun the other ranks may still be reading it."""
    kept = (MANIFEST, "config.json") if keep_config else (MANIFEST,)
    gone = [p for p in ours if p.name not in kept]
    events = sum(p.name.startswith(EVENTS_PREFIX) for p in gone)
    temps = sum(_marked_temp(p.name) for p in gone)
    names = [p.name for p in gone if p.name in RUN_NAMES]
    parts = names + [f"{events} TensorBoard events file(s)"] * bool(events)
    parts += [f"{temps} temporary file(s)"] * bool(temps)
    logger.info("%s holds a run that stopped before its first epoch was saved (no last.pt); %s%s", out_dir, how,
                f" (discarding {', '.join(parts)})" if parts else "")
    for p in gone:
        p.unlink(missing_ok=True)


def claim(out_dir: Path, adopt: bool = False) -> None:
    """Write (or extend) the run manifest of ``out_dir``: the run files, the events files it listed, and
    those now there that carry the events mark; ``adopt`` (resuming a run written before manifests): also its
    unmarked events files."""
    listed = _listed(out_dir)
    names = set(RUN_NAMES) | (listed or set())
    for n in os.listdir(out_dir):
        if is_events(n) or (adopt and listed is None and n.startswith(EVENTS_PREFIX) and "/" not in n):
            if (out_dir / n).is_file() and not (out_dir / n).is_symlink():
                names.add(n)
    write_manifest(out_dir, RUN_KIND, [out_dir / n for n in sorted(names)], digests=False)  # rewritten every epoch


def restart_payload(out_dir: Path) -> dict[str, Any]:
    """What ``--resume`` of a run without ``last.pt`` starts again from: ``{"config", "dataset_path",
    RESTART: seqnet's files there}`` from its ``config.json`` (seqnet's by the manifest, checked); a one-line
    :class:`CheckpointError` saying what to do when the directory holds no run seqnet can start again."""
    from .config import stored_config

    missing = f"checkpoint not found: {out_dir / 'last.pt'}"
    check_links(out_dir)
    ours, other = survey(out_dir)
    if other:
        raise CheckpointError(f"{missing}; {out_dir} holds {other[0]}, which no seqnet run recorded writing, so it "
                              "holds no run to resume or start again (hint: --resume the directory of a run)")
    if out_dir / "config.json" not in ours:
        raise CheckpointError(f"{missing}: the run in {out_dir} stopped before it saved its configuration (hint: "
                              "run the same training command again, with --dataset and --out: it starts the run again)")
    path = out_dir / "config.json"
    values = read_json_object(path, "run configuration", ConfigError, limit=CONFIG_BYTES)
    config = stored_config({k: v for k, v in values.items() if k not in ("model", "role", "seqnet_version")},
                           str(path), ConfigError)
    dataset = config.pop("dataset_path", None)
    return {"config": config, "dataset_path": dataset, RESTART: ours}


def explain_config(path: Path, new: dict[str, Any], kept: tuple[str, ...]) -> None:
    """When resuming, say (WARNING) where the run's ``config.json`` disagreed with its ``last.pt`` (keys other
    than ``kept``, which may change) before it is rewritten from ``last.pt``."""
    if not path.is_file() or path.is_symlink():
        return
    try:
        old = read_json_object(path, "run configuration", ConfigError, limit=CONFIG_BYTES)
    except ConfigError as e:
        logger.warning("%s was unreadable (%s); rewriting it from last.pt", path, str(e)[:160])
        return
    differ = [k for k in new if k not in kept and k != "seqnet_version" and old.get(k) != new[k]]
    if differ:
        logger.warning("%s disagreed with last.pt (%s: %.60r there, %.60r in last.pt); rewriting it from last.pt, "
                       "whose configuration the run continues with", path, differ[0], old.get(differ[0]),
                       new[differ[0]])


def check_resume_target(resume: bool | str | Path, out_dir: Path) -> None:
    """``--resume A`` writes only to A: an ``out_dir`` naming another directory is an error."""
    if not resume or resume is True:
        return
    src = Path(resume)
    run_dir = src.parent if src.is_file() else src
    if run_dir.resolve() != out_dir.resolve():
        raise OutputError(f"--resume {resume} continues the run in {run_dir}, but --out names another directory "
                          f"{out_dir}; a resumed run is written where it is (hint: drop --out, or copy the run "
                          "directory first and resume the copy)")
