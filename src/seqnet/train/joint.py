"""Joint training: S_L and S_1 for HVPR from one command, into one run folder.

``RUN/seqnet/`` is the S_L run (the settings given), ``RUN/s1/`` the S_1 run (the same settings with
``seq_len = w = 1``, its own loss and learning rate, no speed augmentation: an S_1 window of one frame
has no speed), each an ordinary run directory (``best.pt``, ``last.pt``, ``config.json``, TensorBoard);
``RUN/joint.json`` lists them. The two models are trained one after the other on the same data;
resuming a joint run resumes both (the finished one is left as it is).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from ..core.errors import ConfigError
from ..security.files import write_json_atomic
from ..security.locks import locked
from .config import TrainConfig

JOINT_FILE = "joint.json"
JOINT_ROLES = ("seqnet", "s1")
S1_LOSS = "triplet"  # the S_1 loss of a joint run unless given


def s1_config(conf: TrainConfig, loss: str = S1_LOSS, lr: float | None = None,
              margin: float | None = None) -> TrainConfig:
    """The S_1 settings of a joint run whose S_L settings are ``conf`` (lr, margin None: ``conf``'s)."""
    return dataclasses.replace(conf.replace(seq_len=1, w=1, loss=loss, lr=lr, margin=margin), speed_augment=None)


def is_joint(run: str | Path) -> bool:
    """Whether ``run`` is a joint run folder (holds ``joint.json``)."""
    return (Path(run) / JOINT_FILE).is_file()


def joint_configs(conf: TrainConfig, s1: TrainConfig) -> dict[str, TrainConfig]:
    """``{"seqnet": S_L settings, "s1": S_1 settings}``, checked: S_L is a sequence model, S_1 one frame."""
    if conf.seq_len == 1:
        raise ConfigError(f"joint training needs an S_L model with seq_len >= 2, got seq_len={conf.seq_len} "
                          "(hint: --seq-len 5 --w 3; S_1 is trained beside it)")
    if (s1.seq_len, s1.w) != (1, 1):
        raise ConfigError(f"the S_1 model of a joint run needs seq_len = w = 1, got {s1.seq_len}, {s1.w}")
    return {"seqnet": conf, "s1": s1}


def _start(root: Path, confs: dict[str, TrainConfig]) -> None:
    """A new joint run: ``root`` absent or empty; ``joint.json`` records both settings."""
    if root.exists() and (not root.is_dir() or any(root.iterdir())):
        raise ConfigError(f"run directory {root} is not empty (hint: another --out, or --resume {root})")
    with locked(root):
        root.mkdir(parents=True, exist_ok=True)
        write_json_atomic(root / JOINT_FILE, {"runs": {r: r for r in JOINT_ROLES},
                                              "config": {r: c.to_dict() for r, c in confs.items()}})


def main_joint(conf: TrainConfig | None, s1: TrainConfig | None, dataset: str | Path | None, out: str | Path | None,
               resume: str | Path | None = None, allow_mismatch: bool = False,
               changes: dict[str, object] | None = None) -> dict[str, Path]:
    """Train S_L (``conf``) and S_1 (``s1``) into ``out/seqnet`` and ``out/s1``, or resume the joint run
    ``resume`` with its stored settings and ``changes`` (epochs, patience, device; None values keep).
    Returns the run directory of each role."""
    from .loop import main
    from .run import resume_config

    root = Path(out if out is not None else resume if resume is not None else "")
    if not str(root) or str(root) == ".":
        raise ConfigError("no run directory: give --out RUN (or --resume RUN)")
    if resume is None:
        confs = joint_configs(conf or TrainConfig(), s1 or s1_config(conf or TrainConfig()))
        _start(root, confs)
    elif not is_joint(resume):
        raise ConfigError(f"{resume} is not a joint run (no {JOINT_FILE}; hint: resume it without --joint)")
    else:
        stored = json.loads((Path(resume) / JOINT_FILE).read_text())["config"]
        confs = {r: TrainConfig.from_dict(stored[r]) for r in JOINT_ROLES}
    changes = {k: v for k, v in (changes or {}).items() if v is not None} if resume is not None else {}
    out_dirs = {}
    for role in JOINT_ROLES:
        sub = root / role
        if resume is not None and (sub / "last.pt").is_file():
            out_dirs[role] = main(resume_config(sub, **changes), dataset, sub, sub, allow_mismatch)
        else:  # a new run, or the part a resumed joint run had not started
            out_dirs[role] = main(confs[role].replace(**changes), dataset, sub, None, allow_mismatch)
    return out_dirs
