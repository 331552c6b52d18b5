"""Joint training: S_L and S_1 for HVPR from one command, into one run folder.

``RUN/seqnet/`` is the S_L run (the settings given), ``RUN/s1/`` the S_1 run (the same settings with
``seq_len = w = 1``, its own loss and learning rate, no speed augmentation: an S_1 window of one frame
has no speed), each an ordinary run directory (``best.pt``, ``last.pt``, ``config.json``, TensorBoard);
``RUN/joint.json`` records both settings and the dataset, ``RUN/.seqnet-manifest.json`` (kind
``train-joint``) that seqnet wrote it. The two models are trained one after the other on the same data;
resuming a joint run resumes both (the finished one is left as it is, one not saved yet starts again,
the dataset is the recorded one unless ``--dataset`` is given). A new joint run into a folder holding a
joint run of which neither model saved an epoch starts it again; anything else there is refused.
Under torchrun, rank 0 alone checks and writes ``RUN`` and holds its lock for the whole run.
"""

from __future__ import annotations

import contextlib
import dataclasses
from pathlib import Path
from typing import Any

from .._version import __version__
from ..core.errors import ConfigError
from ..core.log import logger
from ..security.files import TEMP_SUFFIX, temp_prefix, write_json_atomic
from ..security.jsonfile import read_json_object
from ..security.locks import lock_file, locked
from ..security.ownership import MANIFEST, read_manifest, write_manifest
from .config import RESUME_OVERRIDABLE, TrainConfig, stored_config
from .distributed import joined
from .rundir import CONFIG_BYTES, survey

JOINT_FILE = "joint.json"
JOINT_KIND = "train-joint"
JOINT_ROLES = ("seqnet", "s1")
S1_LOSS = "triplet"  # the S_1 loss of a joint run unless given


def s1_config(conf: TrainConfig, loss: str = S1_LOSS, lr: float | None = None,
              margin: float | None = None) -> TrainConfig:
    """The S_1 settings of a joint run whose S_L settings are ``conf`` (lr, margin None: ``conf``'s)."""
    return dataclasses.replace(conf.merge(seq_len=1, w=1, loss=loss, lr=lr, margin=margin), speed_augment=None)


def is_joint(run: str | Path) -> bool:
    """Whether ``run`` is a joint run folder (holds ``joint.json``; a link there is refused when it is read)."""
    path = Path(run) / JOINT_FILE
    return path.is_file() or path.is_symlink()


def read_joint(root: Path) -> tuple[dict[str, dict[str, Any]], str | None]:
    """The stored settings of each role and the dataset of the joint run in ``root``, checked
    (:func:`seqnet.train.config.stored_config`); one-line :class:`ConfigError` naming the file otherwise."""
    path = root / JOINT_FILE
    if path.is_symlink():
        raise ConfigError(f"{path} is a symbolic link, not the file seqnet writes; seqnet does not read a run's "
                          "files through links (hint: remove the link)")
    data = read_json_object(path, "joint run file", ConfigError, limit=CONFIG_BYTES)
    stored = data.get("config")
    if not isinstance(stored, dict) or any(r not in stored for r in JOINT_ROLES):
        raise ConfigError(f"{path}: 'config' must hold the settings of {' and '.join(JOINT_ROLES)}")
    confs = {r: stored_config(stored[r], f"{path}: {r}") for r in JOINT_ROLES}
    for c in confs.values():
        c.pop("dataset_path", None)
    dataset = stored_config({"dataset_path": data.get("dataset_path")}, str(path))["dataset_path"]
    return confs, dataset


def joint_configs(conf: TrainConfig, s1: TrainConfig) -> dict[str, TrainConfig]:
    """``{"seqnet": S_L settings, "s1": S_1 settings}``, checked: S_L is a sequence model, S_1 one frame."""
    if conf.seq_len == 1:
        raise ConfigError(f"joint training needs an S_L model with seq_len >= 2, got seq_len={conf.seq_len} "
                          "(hint: --seq-len 5 --w 3; S_1 is trained beside it)")
    if (s1.seq_len, s1.w) != (1, 1):
        raise ConfigError(f"the S_1 model of a joint run needs seq_len = w = 1, got {s1.seq_len}, {s1.w}")
    return {"seqnet": conf, "s1": s1}


def _joint_parts(root: Path) -> tuple[list[str], bool]:
    """``(names in root that are not a joint run's, whether a role saved an epoch)``: a joint run's are its
    manifest (kind ``train-joint``), the ``joint.json`` it lists, their marked temporary files, the roles'
    lock files and run directories holding only seqnet's files (:func:`seqnet.train.rundir.survey`)."""
    manifest = None if (root / MANIFEST).is_symlink() else read_manifest(root)
    listed = manifest is not None and manifest.get("kind") == JOINT_KIND and JOINT_FILE in manifest["files"]
    locks = {lock_file(root / r).name for r in JOINT_ROLES}
    other, saved = [], False
    for p in sorted(root.iterdir()):
        n, regular = p.name, p.is_file() and not p.is_symlink()
        if n in JOINT_ROLES and p.is_dir() and not p.is_symlink():
            saved = saved or (p / "last.pt").exists() or (p / "last.pt").is_symlink()
            other += [f"{n}/{x}" for x in survey(p)[1]]
        elif not (regular and ((listed and n in (MANIFEST, JOINT_FILE)) or n in locks or (n.endswith(TEMP_SUFFIX) and
                  any(n.startswith(temp_prefix(f)) for f in (JOINT_FILE, MANIFEST))))):
            other.append(n)
    return other, saved


def _start(root: Path, confs: dict[str, TrainConfig], dataset: str | Path | None) -> None:
    """A new joint run (under ``root``'s lock): ``root`` absent or empty, or holding a joint run of which no
    role saved an epoch (started again); the manifest, then ``joint.json`` (both settings and the dataset)."""
    if root.exists() and not root.is_dir():
        raise ConfigError(f"run directory {root} is a file (hint: another --out)")
    if root.exists() and any(root.iterdir()):
        other, saved = _joint_parts(root)
        if saved:
            raise ConfigError(f"run directory {root} is not empty: it holds a joint run (hint: another --out, or "
                              f"--resume {root} to continue it)")
        if other:
            raise ConfigError(f"run directory {root} is not empty: it holds {other[0]}, which no seqnet run recorded "
                              "writing there (hint: another --out, or move it away)")
        logger.info("%s holds a joint run that stopped before either model saved an epoch; starting a new one in "
                    "its place", root)
    root.mkdir(parents=True, exist_ok=True)
    write_manifest(root, JOINT_KIND, [root / JOINT_FILE])
    write_json_atomic(root / JOINT_FILE, {"runs": {r: r for r in JOINT_ROLES},
                                          "config": {r: c.to_dict() for r, c in confs.items()},
                                          "dataset_path": str(Path(dataset).resolve()) if dataset else None,
                                          "seqnet_version": __version__})


def main_joint(conf: TrainConfig | None, s1: TrainConfig | None, dataset: str | Path | None, out: str | Path | None,
               resume: str | Path | None = None, allow_mismatch: bool = False,
               changes: dict[str, object] | None = None) -> dict[str, Path]:
    """Train S_L (``conf``) and S_1 (``s1``) into ``out/seqnet`` and ``out/s1``, or resume the joint run
    ``resume`` with its stored settings and dataset (``dataset``: another) and ``changes`` (epochs, patience,
    device; None values keep). Returns the run directory of each role."""
    root = Path(out if out is not None else resume if resume is not None else "")
    if not str(root) or str(root) == ".":
        raise ConfigError("no run directory: give --out RUN (or --resume RUN)")
    if resume is not None and not is_joint(resume):
        raise ConfigError(f"{resume} is not a joint run (no {JOINT_FILE}; hint: resume it without --joint)")
    if resume is not None and Path(resume).resolve() != root.resolve():
        raise ConfigError(f"--resume {resume} continues the joint run there; --out names another directory {root}")
    changes = {k: v for k, v in (changes or {}).items() if v is not None and k in RESUME_OVERRIDABLE}
    with joined() as world, contextlib.ExitStack() as held:
        def claim() -> tuple[dict[str, dict[str, Any]], str | None]:
            held.enter_context(locked(root))  # rank 0 holds the joint run's lock throughout
            if resume is not None:
                return read_joint(root)
            confs = joint_configs(conf or TrainConfig(), s1 or s1_config(conf or TrainConfig()))
            _start(root, confs, dataset)
            return {r: c.to_dict() for r, c in confs.items()}, None

        stored, recorded = world.rank0(claim)
        return _train_roles(root, stored, dataset, recorded, resume is not None, changes, allow_mismatch)


def _train_roles(root: Path, stored: dict[str, dict[str, Any]], dataset: str | Path | None, recorded: str | None,
                 resuming: bool, changes: dict[str, object], allow_mismatch: bool) -> dict[str, Path]:
    from .loop import main
    from .run import resume_config

    if resuming and dataset is not None and recorded is not None and Path(dataset).resolve() != Path(recorded):
        logger.info("resuming %s on %s, not on the dataset it recorded (%s)", root, dataset, recorded)
    out_dirs, finished = {}, _finished_roles(root, changes) if resuming else {}
    for role in JOINT_ROLES:
        sub = root / role
        if role in finished:
            logger.info("%s is already trained to epoch %d of %d; left as it is", sub, finished[role], finished[role])
            out_dirs[role] = sub
            continue
        if resuming and ((sub / "last.pt").is_file() or (sub / "last.pt").is_symlink()):
            out_dirs[role] = main(resume_config(sub, **changes), dataset, sub, sub, allow_mismatch)
            continue
        data = dataset if dataset is not None else recorded  # a new run, or the part a resumed run had not saved
        if data is None:
            raise ConfigError(f"no dataset: the joint run {root} does not record one (written by an older seqnet); "
                              "give --dataset DIR")
        out_dirs[role] = main(TrainConfig.from_dict({**stored[role], **changes}), data, sub, None, allow_mismatch)
    return out_dirs


def _finished_roles(root: Path, changes: dict[str, object]) -> dict[str, int]:
    """Resuming the joint run ``root``: the roles already trained to their epochs (the total, ``changes``'
    or the stored one) and those epochs, left as they are; refused when that total is below a role's epochs
    done, or when both roles are done (nothing would be trained)."""
    from .run import check_epochs_left, read_resume

    finished: dict[str, int] = {}
    for role in JOINT_ROLES:
        if not (root / role / "last.pt").is_file():
            continue
        payload = read_resume(root / role)
        done, epochs = payload.get("epoch"), changes.get("epochs") or payload["config"].get("epochs")
        if not isinstance(done, int) or not isinstance(epochs, int):
            continue
        if epochs < done or (epochs == done and len(finished) == len(JOINT_ROLES) - 1):
            check_epochs_left(done, epochs, root / role)
        if epochs == done:
            finished[role] = done
    return finished
