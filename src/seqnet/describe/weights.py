"""State dicts read from checkpoint files, checked before any module is built from them.

A checkpoint is a stranger's file and a module's size follows the shapes it declares: a VGG-16 built from
the widths of two 1-D "weights" would allocate terabytes before ``load_state_dict`` compared anything. So
``state_dict`` must map names to tensors (:func:`checked_state`), every size read from a shape is in its
range (:mod:`seqnet.security.limits`), and every tensor has the shape the module built from those sizes
will have, with no other tensor (:func:`check_shapes`): the module then holds what the file stores, no more.
"""

from __future__ import annotations

import os
from typing import Any

import torch

from ..core.errors import CheckpointError
from ..security.limits import DIM_MAX, number


def checked_state(state: Any, path: str | os.PathLike[str]) -> dict[str, torch.Tensor]:
    """``state`` when it maps names (text) to tensors; else :class:`CheckpointError` naming the first entry."""
    bad = next(((k, v) for k, v in state.items() if not isinstance(k, str) or not torch.is_tensor(v)), None)
    if bad is not None:
        raise CheckpointError(f"{path}: 'state_dict' must map parameter names to tensors; {str(bad[0])[:60]!r} maps "
                              f"to {type(bad[1]).__name__}")
    return state


def check_shapes(state: dict[str, torch.Tensor], expected: dict[str, tuple[int, ...]], where: str, what: str,
                 optional: tuple[str, ...] = ()) -> None:
    """Every tensor of ``state`` has its ``expected`` shape (those in ``optional`` may be absent), and there is no
    other: checked before a module is built from the shapes, so no layer is larger than what is stored."""
    extra = sorted(set(state) - set(expected))
    if extra:
        raise CheckpointError(f"{where}{extra[0][:80]} is not a weight of {what}")
    for key, shape in expected.items():
        if key not in state:
            if key in optional:
                continue
            raise CheckpointError(f"{where}{key} is missing ({what} needs it, of shape {list(shape)})")
        if tuple(state[key].shape) != shape:
            raise CheckpointError(f"{where}{key} has shape {tuple(state[key].shape)}, expected {list(shape)} ({what})")


def pool_shape(pool: dict[str, torch.Tensor], path: str | os.PathLike[str]) -> tuple[int, int]:
    """``(K, C)`` of a NetVLAD layer's ``centroids [K, C]`` (each in range, K*C a descriptor size), its assignment
    conv ``conv.weight [K, C, 1, 1]`` (and ``conv.bias [K]``) checked to fit."""
    cent = pool["centroids"]
    if cent.ndim != 2:
        raise CheckpointError(f"{path}: pool.centroids has shape {tuple(cent.shape)}, expected [K, C] (K clusters of "
                              "C-D features)")
    k = number(int(cent.shape[0]), f"{path}: pool.centroids' K (clusters)", 1, DIM_MAX, CheckpointError)
    c = number(int(cent.shape[1]), f"{path}: pool.centroids' C (feature size)", 1, DIM_MAX, CheckpointError)
    number(k * c, f"{path}: the NetVLAD descriptor size K*C", 1, DIM_MAX, CheckpointError)
    check_shapes(pool, {"conv.weight": (k, c, 1, 1), "conv.bias": (k,), "centroids": (k, c)}, f"{path}: pool.",
                 f"NetVLAD of {k} clusters x {c}-D", optional=("conv.bias",))
    return k, c


def wpca_shape(wpca: dict[str, torch.Tensor], kc: int, path: str | os.PathLike[str]) -> int:
    """P of a checkpoint's ``WPCA.0.weight [P, K*C, 1, 1]`` (in range), its bias ``[P]`` checked to fit."""
    w = wpca.get("weight")
    if w is None or w.ndim != 4:
        got = "is missing" if w is None else f"has shape {tuple(w.shape)}"
        raise CheckpointError(f"{path}: WPCA.0.weight {got}, expected [P, {kc}, 1, 1]")
    p = number(int(w.shape[0]), f"{path}: WPCA.0.weight's P (output size)", 1, DIM_MAX, CheckpointError)
    check_shapes(wpca, {"weight": (p, kc, 1, 1), "bias": (p,)}, f"{path}: WPCA.0.", f"a WPCA of {kc} -> {p}",
                 optional=("bias",))
    return p
