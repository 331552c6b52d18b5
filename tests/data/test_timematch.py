"""Images whose times are written in another unit than the log's (RobotCar images named in milliseconds against
its ins.csv in microseconds): refused, with a hint that names the units and the fix, not another run's log."""

from __future__ import annotations

import numpy as np
import pytest
from test_gps import T0, write_ins

from seqnet.core.errors import DatasetError
from seqnet.data.gps import log_positions
from seqnet.data.timematch import gap_hint, unit_factor


@pytest.mark.parametrize(("names", "written", "factor"), [
    ([f"{(T0 + k * 20000) // 1000}.png" for k in range(0, 50, 5)], "milliseconds", "1000"),
    ([f"{T0 // 1_000_000 + 1}.png"], "seconds", "1000000"),
])
def test_image_names_in_another_unit_are_named(tmp_path, names, written, factor):
    write_ins(tmp_path / "ins.csv", t0=T0 - 1_000_000, n=150)  # 3 s of log from 1 s before T0
    with pytest.raises(DatasetError, match=rf"no image lies within the log \(the images are from .*\), but the image "
                                           rf"times ×{factor} would lie within the log: they look like {written} "
                                           rf"against a log in microseconds; hint: name the images by their time in "
                                           rf"microseconds \(each name ×{factor}\)$") as err:
        log_positions("robotcar-ins", tmp_path / "ins.csv", names)
    assert "another run" not in str(err.value)


def test_times_in_no_unit_near_the_log_keep_the_other_run_hint():
    """A log of another run (no scaling reaches it) keeps its hint; a clock without a named unit gets the factor."""
    log = np.arange(1000.0, 1010.0, 0.1)
    far = np.array([5.0e8, 5.0e8 + 1])
    assert unit_factor(log, far) is None
    said = gap_hint(log, far, np.arange(2), np.abs(far - 1000), "another drive's oxts folder")
    assert said.endswith("hint: another drive's oxts folder? Give the log recorded with these images")
    ms = np.array([1_000_500.0, 1_005_000.0])  # milliseconds against a log in seconds
    assert unit_factor(log, ms) == 1e-3
    said = gap_hint(log, ms, np.arange(2), np.abs(ms - 1009.9), "another drive's oxts folder")
    assert said.endswith("but the image times ×0.001 would lie within the log; hint: image and log clocks in "
                         "different units? Give both in one unit")


def test_a_factor_below_one_names_the_smaller_unit():
    """Image times 1000× the log's, read in microseconds: named in nanoseconds (a reader may refuse such names
    first: RobotCar's takes at most 18 digits)."""
    log = np.arange(1.4e9, 1.4e9 + 10, 0.1)
    ns = log[::10] * 1e3
    said = gap_hint(log, ns, np.arange(len(ns)), np.abs(ns - log[-1]), "another run's ins.csv", "microseconds")
    assert said.endswith("the image times ×0.001 would lie within the log: they look like nanoseconds against a log "
                         "in microseconds; hint: name the images by their time in microseconds (each name ×0.001)")
