"""Model checkpoints: seqnet's own format and the original SeqNet code's ``*.pth.tar`` files.

seqnet format (``RUN/last.pt``, ``RUN/best.pt``), a ``torch.save`` dict::

    {"format": "seqnet-checkpoint/1", "model": {"in_dims", "out_dims", "seq_len", "w"},
     "state_dict": {"conv.weight": [D_out, D, w], "conv.bias": [D_out]}, "epoch", "best_score",
     "best_epoch", "metrics", "config" (TrainConfig.to_dict()), "dataset_path",
     "val_queries": [a, b) the val split's queries (the best epoch's; None without validation),
     "train_queries" / "train_references": [a, b) the train split's queries / references, "val_references",
     "query_names": "N:HASH" of the query traverse's image names (None without names), "dataset_digests": the
     descriptor files' recorded hashes: what identifies the training queries wherever the data are read again,
     "train_state" (last.pt only): {optimiser, scheduler, generator state, negative cache, ...}}

Original format (``checkpoint.pth.tar`` / ``model_best.pth.tar``): ``{"state_dict":
{"pool.0.conv.weight", "pool.0.conv.bias"}, "epoch", "best_score", ...}``, with the run's flags
(``seqL``, ``w``, ``outDims``, ``pooling``) in ``checkpoints/flags.json`` beside it (read by
:mod:`seqnet.sequence.original`).

Checkpoints are read with :func:`seqnet.security.torchfile.load_torch_file` (``torch.load(weights_only=True)``):
they can hold tensors and plain data only, never code.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from ..core.errors import CheckpointError
from ..core.lazy import lazy_module
from ..core.log import logger
from ..security.files import atomic_path
from ..security.limits import DIM_MAX, SEQ_MAX, number
from ..security.torchfile import load_torch_file
from .original import original_model

torch = lazy_module("torch")

if TYPE_CHECKING:
    from .model import SeqNet

CHECKPOINT_FORMAT = "seqnet-checkpoint/1"
#: What a checkpoint records of its training data that ``trained_on`` carries (besides dataset, split, val split).
TRAINED_ON = ("val_queries", "train_queries", "trained_queries", "query_names", "dataset_digests")


def save_checkpoint(path: str | Path, model: SeqNet, **fields: Any) -> Path:
    """Write ``model`` (architecture + weights) and ``fields`` to ``path`` atomically."""
    payload = {"format": CHECKPOINT_FORMAT, "model": model.config(), "provenance": model.provenance,
               "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()}, **fields}
    path = Path(path)
    with atomic_path(path) as tmp:  # a write cut short (torch's "inline_container" error) is "disk full", exit 1
        torch.save(payload, tmp)
    return path


def read_checkpoint(path: str | Path, mapped: bool = False) -> dict[str, Any]:
    """Load a checkpoint file as a dict (:func:`seqnet.security.torchfile.load_torch_file`; ``mapped``: its
    tensors mapped from the file, not read); :class:`CheckpointError` if missing, unreadable or not a checkpoint."""
    path = Path(path)
    if path.is_dir():
        raise CheckpointError(f"checkpoint not found: {path} (it is a directory; {_in_folder(path)})")
    payload = load_torch_file(path, "checkpoint", mapped=mapped)
    if not isinstance(payload, dict) or "state_dict" not in payload:
        got = f"dict with keys {list(payload)[:8]}" if isinstance(payload, dict) else type(payload).__name__
        raise CheckpointError(f"{path} is not a SeqNet checkpoint: expected a dict with a 'state_dict', got {got}")
    state = payload["state_dict"]
    if not isinstance(state, dict) or not all(isinstance(k, str) and torch.is_tensor(v) for k, v in state.items()):
        raise CheckpointError(f"{path}: 'state_dict' must map parameter names to tensors, got "
                              f"{type(state).__name__}")
    return payload


def _in_folder(path: Path) -> str:
    """What to pass for the folder ``path``: the checkpoints it holds (``RUN/best.pt``, or each model's of a joint
    run: ``RUN/seqnet/best.pt`` and ``RUN/s1/best.pt``, with their kind), else RUN/best.pt."""
    try:
        found = [p for p in (path / "best.pt", *sorted(path.glob("*/best.pt"))[:4]) if p.is_file()]
        kinds = {p: "S_1" if model_role(p).role == "s1" else "S_L" for p in found}
    except (OSError, CheckpointError):
        found, kinds = [], {}
    if not found:
        return "pass RUN/best.pt, the checkpoint of a training run"
    if len(found) == 1 or len(set(kinds.values())) < len(found):
        return f"pass {' or '.join(map(str, found))}"
    return f"pass its checkpoints, one --model each: {' and '.join(f'{p} ({kinds[p]})' for p in found)}"


def load_model(path: str | Path, seq_len: int | None = None, in_dims: int | None = None) -> SeqNet:
    """The SeqNet model stored in a checkpoint (seqnet or original format), on CPU, in eval mode.

    Args:
        path: checkpoint file.
        seq_len: sequence length L the model was trained with, for an original checkpoint without
            ``flags.json`` only (a stored L is never changed; evaluating at another L >= w is valid and runs,
            the convolution averaged over that window's ``L - w + 1`` outputs: :func:`seqnet.eval.evaluate.evaluate`
            logs one INFO line and records ``model_seq_len`` in the results; L < w is refused).
        in_dims: expected input dimension D (e.g. the dataset's); a mismatch raises CheckpointError.

    The model's ``provenance`` is that of the descriptors it was trained on (None when unknown), its
    ``trained_on`` the dataset directory and split of its training queries, the split its epoch was chosen on
    (``val_split``, ``"none"`` without validation) and that split's query range (``val_queries``, ``[a, b]``;
    None for checkpoints written before training recorded it), the train split's query range (``train_queries``),
    how many of its queries the model trained on (``trained_queries``: those with a full window, a positive and a
    negative; None for checkpoints written before 2026-12-05) and what identifies those queries (``query_names``,
    ``dataset_digests``) (None when unknown)
    """
    payload = read_checkpoint(path)
    fmt = payload.get("format")
    if isinstance(fmt, str) and fmt.startswith("seqnet-checkpoint/") and fmt != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{path} is a checkpoint of format {fmt[:40]!r}, written by a newer seqnet; this seqnet "
                              f"reads {CHECKPOINT_FORMAT!r} (hint: upgrade seqnet: pip install -U seqnet)")
    if fmt == CHECKPOINT_FORMAT:
        model = _build(payload.get("model"), payload["state_dict"], Path(path))
        model.provenance = payload.get("provenance") if isinstance(payload.get("provenance"), dict) else None
        config = payload.get("config") if isinstance(payload.get("config"), dict) else {}
        model.trained_on = {"dataset": payload.get("dataset_path"), "split": config.get("train_split"),
                            "checkpoint": str(path), "val_split": config.get("val_split"),
                            **{k: payload.get(k) for k in TRAINED_ON}} if payload.get("dataset_path") else None
    else:
        model = _build(*original_model(payload, Path(path), seq_len), Path(path))
    if in_dims is not None and in_dims != model.in_dims:
        raise CheckpointError(f"{path} expects D={model.in_dims} input descriptors but the data has D={in_dims} "
                              "(hint: use the descriptors the model was trained on)")
    return model.eval()


def check_architecture(cfg: Any, state: dict[str, torch.Tensor], path: Path) -> tuple[int, int, int, int]:
    """``(in_dims, out_dims, seq_len, w)`` of a checkpoint's architecture entry, each in its range and equal to
    the shapes of the stored weights (``conv.weight [out, in, w]``, ``conv.bias [out]``): checked before the
    model is built, so a declared size never allocates beyond the file's own weights."""
    if not isinstance(cfg, dict):
        raise CheckpointError(f"{path}: no 'model' architecture entry (in_dims, out_dims, seq_len, w)")
    try:
        dims = tuple(int(number(cfg.get(k), f"{path}: model {k}", 1, hi, CheckpointError)) for k, hi in (
            ("in_dims", DIM_MAX), ("out_dims", DIM_MAX), ("seq_len", SEQ_MAX), ("w", SEQ_MAX)))
    except CheckpointError as e:
        raise CheckpointError(f"{e} (the stored architecture is {str(cfg)[:120]})") from e
    in_dims, out_dims, seq_len, w = dims
    weight, bias = state.get("conv.weight"), state.get("conv.bias")
    if weight is None or bias is None or tuple(weight.shape) != (out_dims, in_dims, w) or \
            tuple(bias.shape) != (out_dims,) or w > seq_len:
        got = {k: tuple(v.shape) for k, v in list(state.items())[:4]}
        raise CheckpointError(f"{path}: weights do not fit the stored architecture {cfg} (weights {got}; "
                              "conv.weight [out_dims, in_dims, w] and conv.bias [out_dims] expected, w <= seq_len)")
    return in_dims, out_dims, seq_len, w


def _build(cfg: dict[str, Any], state: dict[str, torch.Tensor], path: Path) -> SeqNet:
    from .model import SeqNet  # the model class loads torch

    in_dims, out_dims, seq_len, w = check_architecture(cfg, state, path)
    try:
        model = SeqNet(in_dims, out_dims, seq_len, w)
        model.load_state_dict(state)
    except (KeyError, TypeError, ValueError, RuntimeError, AttributeError) as e:
        reason = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise CheckpointError(f"{path}: weights do not fit the stored architecture {cfg} ({reason})") from e
    bad = [name for name, p in model.state_dict().items() if not bool(torch.isfinite(p).all())]
    if bad:
        raise CheckpointError(f"{path}: the weights {', '.join(bad)} hold NaN or inf (a diverged or corrupted "
                              "training run); hint: use an earlier checkpoint (best.pt) or retrain")
    return model


class Role(NamedTuple):
    """A checkpoint's role and L, as :func:`model_role` reads them."""

    role: str
    seq_len: int


def model_role(path: str | Path) -> Role:
    """``(role, L)`` of the model in a checkpoint (``"s1"`` or ``"seqnet"``, as :attr:`SeqNet.role`), its weights
    mapped from the file and never read into memory: what a command learns of a model it will not use. An
    original-code checkpoint is loaded."""
    payload = read_checkpoint(path, mapped=True)
    if payload.get("format") != CHECKPOINT_FORMAT:
        model = load_model(path)
        return Role(model.role, model.seq_len)
    _, _, seq_len, w = check_architecture(payload.get("model"), payload["state_dict"], Path(path))
    return Role("s1" if seq_len == 1 and w == 1 else "seqnet", seq_len)


def load_models(paths: Sequence[str | Path] | str | Path = (), shortlist_model: str | Path | None = None,
                rerank_model: str | Path | None = None, seq_len: int | None = None) -> dict[str, SeqNet]:
    """Models by role: ``paths`` (a list of checkpoints; one path alone is taken as a list of one) by their stored
    role, then the S_L ``shortlist_model`` (an original checkpoint without flags.json takes ``seq_len``) and the
    S_1 ``rerank_model``."""
    if isinstance(paths, (str, os.PathLike)):  # one checkpoint, not its characters
        paths = [paths]
    models, seen = {}, {}
    for path in paths:
        model = load_model(path)
        models.update({} if one_per_role(seen, model, path, "--model") else {model.role: model})
    for role, path in (("seqnet", shortlist_model), ("s1", rerank_model)):
        if path:
            model = _as_role(load_model(path, seq_len=seq_len) if role == "seqnet" else load_model(path), role, path)
            models.update({} if one_per_role(seen, model, path, FLAGS[role]) else {role: model})
    return models


FLAGS = {"seqnet": "--shortlist-model", "s1": "--rerank-model"}  # the flag of a checkpoint of one role


def one_per_role(seen: dict[str, tuple], model: Any, path: str | Path, flag: str) -> bool:
    """Record in ``seen`` the checkpoint ``path`` (given with ``flag``) of ``model`` (its ``role``, ``seq_len``);
    a second one of its role is refused (it would replace the first, and an S_L the L of the whole run). True
    when ``path`` is the file already recorded (given twice: one model)."""
    if model.role not in seen:
        seen[model.role] = (flag, path, model.seq_len)
        return False
    first = seen[model.role]
    if Path(first[1]).resolve() == Path(path).resolve():
        return True
    kind = "S_1" if model.role == "s1" else f"S_L (L={model.seq_len}; the first has L={first[2]})"
    raise CheckpointError(f"{flag} {path} is a second {kind}, beside {first[0]} {first[1]}: a run uses one S_1 and "
                          f"one S_L; to compare them, evaluate each in a run of its own (one {flag} each)")


def _as_role(model: SeqNet, role: str, path: str | Path) -> SeqNet:
    """``model`` given by the flag of ``role``, refused when it is the other kind (the two flags swapped)."""
    if model.role == role:
        return model
    flag, other = ("--shortlist-model", "--rerank-model") if role == "seqnet" else ("--rerank-model",
                                                                                   "--shortlist-model")
    kind = "an S_1 (L=1, w=1)" if model.role == "s1" else f"an S_{model.seq_len} (L={model.seq_len}, w={model.w})"
    raise CheckpointError(f"{flag} {Path(path).name} is {kind}, not {'an S_L' if role == 'seqnet' else 'an S_1'}: "
                          f"give it as {other} (the two swapped?), or as --model, which reads each model's kind")


class UsedModels(NamedTuple):
    """The checkpoints a command's methods use (:func:`used_models`): the ``--model`` paths, the S_L
    ``--shortlist-model`` and the S_1 ``--rerank-model`` (None when unused or not given), the file names of those
    it will not load (as given: two ``best.pt`` of different runs stay apart), and the L of an unused S_L (None when
    none): a command without L takes its windows from it."""

    paths: list[str | Path]
    shortlist_model: str | Path | None
    rerank_model: str | Path | None
    unused: list[str]
    seq_len: int | None


def used_models(by: str, needed: set[str], paths: Sequence[str | Path] = (),
                shortlist_model: str | Path | None = None, rerank_model: str | Path | None = None) -> UsedModels:
    """Split the checkpoints given by the roles ``needed`` (``"seqnet"``, ``"s1"``): each ``--model``'s role is
    looked up with its weights mapped, not read (:func:`model_role`), so a model no method uses is never loaded
    (S_L at D = 16384 is 5 GB); one line names those left out and ``by``, the methods that do not use them."""
    unused, seq_len, seen = [], None, {}
    listed = []
    for path in paths:
        role, length = found = model_role(path)
        if one_per_role(seen, found, path, "--model"):
            continue
        if role in needed:
            listed.append(path)
            continue
        unused.append(str(path))
        seq_len = length if role == "seqnet" and seq_len is None else seq_len
    named = {}
    for path, role in ((shortlist_model, "seqnet"), (rerank_model, "s1")):
        if path and role in seen and (found := model_role(path)).role == role and \
                one_per_role(seen, found, path, FLAGS[role]):  # another kind: refused, named, when loaded
            continue
        if path and role in needed:
            named[role] = path
        elif path:
            unused.append(str(path))
            if role == "seqnet" and seq_len is None:  # its L only: mapped, not loaded
                seq_len = model_role(path)[1]
    if unused:
        logger.info("%s %s not use the model%s %s: not loaded", by, "does" if "," not in by else "do",
                    "s" * (len(unused) > 1), ", ".join(unused))
    return UsedModels(listed, named.get("seqnet"), named.get("s1"), unused, seq_len)
