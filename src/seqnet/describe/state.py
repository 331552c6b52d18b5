"""Fitted state kept beside an output file (``<stem>.pca.npz``, ``<stem>.netvlad.pth.tar``) and who owns it.

Every state file seqnet writes carries a *tag*: the name of the output it was fitted for, the
settings and the list of images it was fitted with. A run reuses a state file whose tag matches, replaces one that was
written for the same output with other settings, and refuses to touch any other file of that name
(a user's file, or another output's state): it never deletes or overwrites what it did not write.
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Callable, Sequence
from pathlib import Path

from ..core.errors import ConfigError
from ..core.log import logger
from ..core.provenance import fit_digest
from .config import DescribeConfig, fit_summary
from .images import ImageItem, image_key
from .pca import read_tag as read_pca_tag
from .views import RAW

PCA_SUFFIX = ".pca.npz"


@dataclasses.dataclass(frozen=True)
class StateFile:
    """A fitted-state file beside an output, and the tag that marks it as fitted for that output."""

    path: Path
    what: str
    tag: str
    read_tag: Callable[[Path], str | None]

    def owned(self) -> bool:
        """Whether it exists and was written for this output (with any settings)."""
        found = self.read_tag(self.path) if self.path.exists() else None
        return found is not None and _output_of(found) == _output_of(self.tag)

    def reusable(self) -> bool:
        """True: it exists with this tag (reuse it). False: it is absent, or it was written for the same
        output with other settings (fit again and replace it). :class:`ConfigError` when it exists and
        was not written for this output."""
        if not self.path.exists():
            return False
        found = self.read_tag(self.path)
        if found == self.tag:
            return True
        if found is not None and _output_of(found) == _output_of(self.tag):
            logger.info("%s was fitted with other settings; fitting the %s again", self.path, self.what)
            return False
        raise ConfigError(f"{self.path} exists and was not written for {_output_of(self.tag)}; refusing to "
                          f"overwrite it with the {self.what} of this run (hint: move or rename it, or choose "
                          "another --out)")


def state_tag(conf: DescribeConfig, output: str | os.PathLike[str], fit_paths: Sequence[Path | ImageItem] = (),
              view: str = RAW) -> str:
    """The tag of state fitted for ``output`` with the settings of ``conf`` on the images ``fit_paths`` (in their
    ``view``, named in the tag when the config has several: :mod:`seqnet.describe.views`)."""
    fitted_on = fit_summary(tuple(str(p) for p in fit_paths))
    per_view = {"view": view} if len(conf.views) > 1 else {}
    return json.dumps({"output": Path(output).name, "settings": conf.settings(), "fit_images": fitted_on,
                       "provenance_fit": provenance_fit(fit_paths), **per_view}, sort_keys=True)  # a reuser records


def provenance_fit(paths: Sequence[str | os.PathLike[str] | ImageItem]) -> str:
    """The hash of the images fitted state was computed on, as the descriptors' provenance records it."""
    return fit_digest(image_key(p) for p in paths)


def reused_fit(conf: DescribeConfig, settings: dict | None = None) -> str | None:
    """The provenance fit hash of the state fitted by seqnet that ``conf --checkpoint`` reuses, when its
    run had this run's settings (a NetVLAD fitted on the reference, reused for the query): the
    descriptors are then those that run would make. None otherwise (another tool's checkpoint).
    ``settings``: ``conf.settings()`` when the caller has them already."""
    path = getattr(conf.method_spec, "checkpoint", None)
    tag = conf.method_spec.read_tag(Path(path)) if path else None
    try:
        found = json.loads(tag) if tag else None
    except (ValueError, RecursionError):
        return None
    # the tag is read from a file: its fit hash must be text and its settings a mapping, else it is not reused
    if not isinstance(found, dict) or not isinstance(found.get("provenance_fit"), str) or not found["provenance_fit"] \
            or not isinstance(found.get("settings"), dict):
        return None
    ignore = ("fit", "fit_max", "checkpoint", "dim", "whiten")
    ours = {k: v for k, v in (settings or conf.settings()).items() if k not in ignore}
    theirs = {k: v for k, v in found["settings"].items() if k not in ignore}
    return found["provenance_fit"] if ours == theirs else None


def _output_of(tag: str) -> str | None:
    try:
        found = json.loads(tag)
    except (ValueError, RecursionError):
        return None
    output = found.get("output") if isinstance(found, dict) else None
    return output if isinstance(output, str) else None


def pca_file(conf: DescribeConfig, output: str | os.PathLike[str] | None,
             fit_paths: Sequence[Path | ImageItem] = ()) -> StateFile | None:
    """The PCA file of ``conf`` beside ``output`` (None without PCA or output)."""
    if output is None or conf.dim is None:
        return None
    path = Path(output).with_suffix("")
    tag = state_tag(conf, output, fit_paths)
    return StateFile(path.with_name(path.name + PCA_SUFFIX), "PCA", tag, read_pca_tag)


def method_state_file(conf: DescribeConfig, output: str | os.PathLike[str] | None,
                      fit_paths: Sequence[Path | ImageItem] = (), view: str = RAW) -> StateFile | None:
    """The file of the method's fitted state (NetVLAD clusters) of ``view`` beside ``output`` (``<stem>.VIEW<suffix>``
    for a view other than the first of several); None when it fits none."""
    method = conf.method_spec
    if output is None or not method.fits_state or method.state_suffix is None:
        return None
    path = Path(output).with_suffix("")
    no_pca = dataclasses.replace(conf, dim=None, whiten=False)  # the PCA does not change this state
    tag = state_tag(no_pca, output, fit_paths, view)
    infix = f".{view}" if view != conf.views[0] else ""
    return StateFile(path.with_name(path.name + infix + method.state_suffix),
                     f"{method.name} state" + (f" ({view})" if infix else ""), tag, method.read_tag)


def state_files(conf: DescribeConfig, output: str | os.PathLike[str] | None,
                fit_paths: Sequence[Path | ImageItem] = ()) -> list[StateFile]:
    """The fitted-state files a run of ``conf`` writing ``output`` (fitting on ``fit_paths``) reads and writes."""
    files = (*(method_state_file(conf, output, fit_paths, v) for v in conf.views), pca_file(conf, output, fit_paths))
    return [f for f in files if f is not None]
