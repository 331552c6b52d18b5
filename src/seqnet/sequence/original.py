"""The original SeqNet code's checkpoints (``checkpoint.pth.tar`` / ``model_best.pth.tar``): a ``state_dict`` with
``pool.0.conv.weight`` [D_out, D, w] and ``pool.0.conv.bias`` [D_out], and the run's flags (``seqL``, ``w``,
``outDims``, ``pooling``) in ``flags.json`` beside it or in ``checkpoints/``. The model is built by
:func:`seqnet.sequence.checkpoints.load_model`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..core.errors import CheckpointError
from ..core.lazy import lazy_module
from ..core.log import logger
from ..security.jsonfile import read_json

torch = lazy_module("torch")


def find_flags(path: Path) -> Path | None:
    """``flags.json`` of an original-code run: beside the checkpoint, or in ``checkpoints/`` of its folder
    (never further up: a file is read from the checkpoint's own folder only)."""
    here = path.resolve().parent
    for cand in (here / "flags.json", here / "checkpoints" / "flags.json"):
        if cand.is_file():
            return cand
    return None


def _original_weights(payload: dict[str, Any], path: Path) -> tuple[torch.Tensor, torch.Tensor]:
    state = {k.removeprefix("module."): v for k, v in payload["state_dict"].items()}
    weights = [k for k in state if k.endswith("conv.weight")]
    if len(weights) != 1 or not torch.is_tensor(state[weights[0]]) or state[weights[0]].ndim != 3:
        raise CheckpointError(f"{path}: expected one Conv1d weight 'pool.0.conv.weight' [D_out, D, w] in state_dict, "
                              f"found keys {sorted(state)[:8]}")
    bias = state.get(weights[0][: -len("weight")] + "bias")
    if bias is None:
        raise CheckpointError(f"{path}: state_dict has {weights[0]} but no matching conv bias")
    return state[weights[0]], bias


def read_flags(path: Path) -> dict[str, Any]:
    """The original run's ``flags.json`` (empty when absent), with ``seqL``, ``w``, ``outDims`` checked to be
    integers >= 1; :class:`CheckpointError` naming the file and key otherwise."""
    flags_path = find_flags(path)
    if flags_path is None:
        return {}
    flags = read_json(flags_path, "flags file", CheckpointError, limit=1 << 20)
    if not isinstance(flags, dict):
        raise CheckpointError(f"{flags_path}: must hold a JSON object of the run's flags")
    for key in ("seqL", "w", "outDims"):
        value = flags.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
            raise CheckpointError(f"{flags_path}: {key} must be an integer >= 1, got {value!r}")
    return flags


def original_model(payload: dict[str, Any], path: Path, seq_len: int | None) -> tuple[dict[str, int], dict[str, Any]]:
    """The architecture ``{in_dims, out_dims, seq_len, w}`` and the weights ``{conv.weight [D_out, D, w], conv.bias
    [D_out]}`` of an original checkpoint ``payload`` read from ``path``, its flags.json checked against the weights;
    ``seq_len`` for a checkpoint without flags.json giving seqL."""
    weight, bias = _original_weights(payload, path)
    out_dims, in_dims, w = (int(x) for x in weight.shape)
    flags = read_flags(path)
    for key, actual in (("w", w), ("outDims", out_dims)):
        if flags.get(key) is not None and flags[key] != actual:
            raise CheckpointError(f"{find_flags(path)}: {key}={flags[key]} does not match the weights "
                                  f"{tuple(weight.shape)} in {path}")
    stored = 1 if str(flags.get("pooling", "")).lower() == "s1+seqmatch" else flags.get("seqL")
    if seq_len is None and stored is None:
        raise CheckpointError(f"{path}: original SeqNet checkpoint (D={in_dims} → {out_dims}, w={w}) without "
                              "flags.json giving seqL; pass the sequence length (seqnet eval --seq-len L, or "
                              "load_model(path, seq_len=L))")
    cfg = {"in_dims": in_dims, "out_dims": out_dims, "seq_len": int(stored if stored is not None else seq_len), "w": w}
    logger.info("loaded original SeqNet checkpoint %s (epoch %s): %s", path, payload.get("epoch"), cfg)
    return cfg, {"conv.weight": weight, "conv.bias": bias}
