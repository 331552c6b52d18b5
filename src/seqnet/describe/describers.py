"""TEMPORARY compatibility shim: the pre-:class:`DescribeConfig` call of :mod:`seqnet.pipelines.nordland64`.

``make_describer(method, paths, **options)`` and ``describer.opts.resolved_size(method)`` /
``describer.opts.crop_bottom`` as nordland64 (and its test) still use them. Delete this module once
nordland64 calls ``seqnet.describe.make_describer(DescribeConfig(...), paths)`` and ``describer.load``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from types import SimpleNamespace
from typing import Any

from .config import NATIVE, DescribeConfig
from .describer import Describer
from .describer import make_describer as make_configured


class LegacyDescriber(Describer):
    """A :class:`Describer` with the old ``opts`` view."""

    @property
    def opts(self) -> SimpleNamespace:
        size = self.config.image_size
        return SimpleNamespace(crop_bottom=self.config.crop_bottom, resolved_size=lambda method: size)


def make_describer(method: str, paths: Sequence[str | os.PathLike[str]] = (), **options: Any) -> LegacyDescriber:
    """The old signature: ``size=None`` meant native; ``progress`` is now global (ignored)."""
    options.pop("progress", None)
    if "size" in options and options["size"] is None:
        options["size"] = NATIVE
    d = make_configured(DescribeConfig.from_dict({"method": method, **options}), paths)
    return LegacyDescriber(d.config, d.extract, d.pca)
