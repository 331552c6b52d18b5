"""Config.replace applies every change, None included; Config.merge (the CLI's) keeps a field given None."""

from __future__ import annotations

import pytest

from seqnet.core.errors import ConfigError
from seqnet.eval.config import EvalConfig
from seqnet.train.config import TrainConfig


def test_replace_none_clears_a_field_and_merge_keeps_it():
    """Hostile 52 M3: conf.replace(target_precision=None, radius=None, split=None) kept 0.8, 20.0 and 'val', so
    a Python user could not turn calibration off nor go back to the dataset's radius, without a word."""
    conf = EvalConfig(target_precision=0.8, radius=20.0, split="val")
    cleared = conf.replace(target_precision=None, radius=None, split=None)
    assert (cleared.target_precision, cleared.radius, cleared.split) == (None, None, None)
    assert conf.merge(target_precision=None, radius=None, split=None) == conf  # an option not given
    assert conf.merge(radius=5.0).radius == conf.replace(radius=5.0).radius == 5.0
    with pytest.raises(ConfigError, match="lr"):
        TrainConfig().replace(lr=None)  # a field that has no None: refused, not kept
    with pytest.raises(ConfigError, match="unknown"):
        conf.replace(nope=1)
