"""MSLS's predictions file (mapillary/mapillary_sls ``evaluate.py``) for one method of an evaluation.

``evaluate.py`` reads the file with ``np.loadtxt``: whitespace-separated columns, ``#`` lines are
comments, and every row must have the same number of columns. Column 0 is a query key, the rest its
predicted database keys, best first (it reads up to 20). A key is an image name's basename without its
extension; for a sequence task it is the keys of the L frames of a window, comma-joined in order
(MSLS's ``arange_as_seq``: L consecutive rows of one sequence, centred on the frame). Every query key
it scores must have a row, and no row may predict a key twice.

What a method ranks decides the task: a single-frame method (``single``, ``s1``) compares one query
frame with one reference frame: ``--task im2im``, a row per query frame. Every other method (sequence
descriptors, sequence matchers, HVPR) compares a query window with reference windows: ``--task
seq2seq --seq-length L`` with L the frames its windows span (max(L, L_m)), a row per query window
whose keys are the window's frames. MSLS's windows are centred and of odd length; others are refused.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import ConfigError
from ..core.log import logger
from ..methods.grammar import parse_method
from ..sequence.windows import window_offset
from .evaluation import ItemView

MSLS_TOP = 20  # predictions per query in an MSLS file (its evaluation reads up to 20)
MSLS_MARK = "# seqnet "  # the first line of an MSLS file seqnet writes (a comment np.loadtxt skips): its mark


def msls_task(method: str, view: ItemView) -> tuple[str, int]:
    """``(task, seq_length)`` of MSLS's ``evaluate.py`` that matches what ``method`` ranks (see the module)."""
    if parse_method(method).single_frame:
        return "im2im", 1
    w = view.windows
    if w is None or w.mode != "centred" or w.longest % 2 == 0:
        what = "unknown windows" if w is None else f"{w.mode} windows of {w.longest} frames"
        raise ConfigError(f"an MSLS predictions file of {method} needs centred windows of an odd length (MSLS's "
                          f"seq2seq), got {what}; hint: --window centred --seq-len 3 or 5")
    return "seq2seq", w.longest


def window_keys(names: list[str], items: np.ndarray, length: int) -> list[str]:
    """``[M]`` MSLS keys of the centred ``length``-frame windows of the frames ``items``: their frames' image
    basenames without extension, comma-joined (one frame: its own key)."""
    stems = [Path(n).stem for n in names]
    bad = next((s for s in stems if not s or s.startswith("#") or any(c.isspace() or c == "," for c in s)), None)
    if bad is not None:
        raise ConfigError(f"image name {bad!r} cannot be an MSLS key (empty, or holding a space, a comma or a '#')")
    first = np.asarray(items, dtype=np.int64) - window_offset(length, "centred")
    return [",".join(stems[s : s + length]) for s in first.tolist()]


def _unique(keys: list[str], side: str) -> None:
    if len(set(keys)) != len(keys):
        dup = next(k for i, k in enumerate(keys) if k in keys[:i])
        raise ConfigError(f"two {side} items have the MSLS key {dup!r} (image basenames must be unique)")


def _rows(ranked: np.ndarray, n_refs: int, method: str) -> list[list[int]]:
    """The first ``width`` valid predictions of every row, ``width`` the fewest any row has (MSLS's rows must
    be equally wide)."""
    valid = [row[row >= 0] for row in np.asarray(ranked)[:, :MSLS_TOP]]
    width = min((len(v) for v in valid), default=0)
    if valid and width == 0:
        raise ConfigError(f"{method} ranked no reference for some query: an MSLS row needs at least one prediction")
    if width < min(MSLS_TOP, n_refs):
        logger.warning("MSLS predictions of %s: %d per query (not %d): every row must be as wide (np.loadtxt), "
                       "and some query has only %d", method, width, min(MSLS_TOP, n_refs), width)
    return [v[:width].tolist() for v in valid]


def msls_predictions(ev: Any) -> str:
    """MSLS's predictions file of the evaluation's one method (see the module): a ``#`` line naming the method
    and the ``evaluate.py`` options to score it with, then one row per query item, its key and its top-20
    reference keys. The image names of every frame must be known."""
    if len(ev.retrieved) != 1:
        raise ConfigError(f"an MSLS predictions file holds one method, got {len(ev.retrieved)} "
                          f"({', '.join(ev.retrieved)}); hint: --method M")
    q_names, r_names = ev.frame_names
    if q_names is None or r_names is None:
        raise ConfigError("an MSLS predictions file needs image names for the query and reference images")
    name, ranked = next(iter(ev.retrieved.items()))
    view = ev.view(name)
    task, length = msls_task(name, view)
    if task == "im2im" and len(view.q_items) != len(q_names):
        raise ConfigError(f"an MSLS im2im file needs a row for every query image, but {name} was evaluated on "
                          f"{len(view.q_items)} of {len(q_names)} (the frames with a full window: --common-queries or "
                          "a map); hint: evaluate the dataset without --common-queries")
    q_keys, r_keys = window_keys(q_names, view.q_items, length), window_keys(r_names, view.r_items, length)
    _unique(q_keys, "query")
    _unique(r_keys, "reference")
    options = f"--task {task}" + (f" --seq-length {length}" if task != "im2im" else "")
    logger.info("MSLS predictions of %s: %d query %s; score them with mapillary_sls evaluate.py %s",
                name, len(q_keys), "images" if task == "im2im" else f"windows of {length} frames", options)
    rows = _rows(ranked, len(r_keys), name)
    head = f"{MSLS_MARK}{name}: mapillary_sls evaluate.py {options}\n"
    return head + "".join(" ".join([q, *(r_keys[j] for j in row)]) + "\n" for q, row in zip(q_keys, rows, strict=True))
