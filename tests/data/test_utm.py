"""Lat/lon positions: out-of-range values name their line and whether the columns are swapped; two traverses whose
lat and lon meet only once one is swapped are refused; else both become UTM metres in the reference's zone."""

from __future__ import annotations

import numpy as np
import pytest

from seqnet.core.errors import DatasetError
from seqnet.data.utm import check_latlon, latlon_pair


def test_check_latlon_names_the_line_and_the_cause():
    check_latlon(np.array([[66.0, 14.0], [-33.9, 151.2]]), "ok.csv")  # in range: nothing said
    with pytest.raises(DatasetError, match=r"^p.csv, line 3: latitude 151.2, longitude -33.9 out of range .*hint: "
                                           "the lat and lon columns are swapped"):
        check_latlon(np.array([[14.0, 66.0], [151.2, -33.9]]), "p.csv", [2, 3])
    with pytest.raises(DatasetError, match=r"row 0: latitude 6e\+06.*metres under lat/lon names"):
        check_latlon(np.array([[6e6, 5e5]]), "p.csv")
    e7 = np.array([[634300000, 103900000], [634300900, 103902000]], dtype=np.float64)  # degrees × 1e7
    with pytest.raises(DatasetError, match=r"hint: degrees × 10\^7 .*divide the lat and lon columns by 1e7$"):
        check_latlon(e7, "p.csv")
    with pytest.raises(DatasetError, match=r"degrees × 10\^6 .*by 1e6; or metres under lat/lon names"):
        check_latlon(np.round(e7 / 10), "p.csv")  # E6 and UTM metres can look alike: both said
    with pytest.raises(DatasetError, match=r"hint: metres under lat/lon names"):
        check_latlon(e7 + 0.5, "p.csv")  # not whole numbers: no scaled degrees


def test_latlon_pair_is_metres_in_the_reference_zone_and_refuses_a_swapped_file():
    ref = np.stack([66.0 + np.arange(5) * 10 / 111320, np.full(5, 14.0)], axis=1)
    qry = ref + [3 / 111320, 0.0]
    r, q, frame = latlon_pair(ref, qry, ("r.csv", "q.csv"))
    assert frame == "UTM zone 33W"
    np.testing.assert_allclose(np.linalg.norm(np.diff(r, axis=0), axis=1), 10.0, rtol=0.01)
    np.testing.assert_allclose(np.linalg.norm(q - r, axis=1), 3.0, rtol=0.02)
    with pytest.raises(DatasetError, match=r"^the lat and lon columns of r.csv or of q.csv look swapped: as given "
                                           r"their positions lie 52.0 degrees apart"):
        latlon_pair(ref, qry[:, ::-1], ("r.csv", "q.csv"))
    far = ref + [0.0, 3.0]  # another place (3 degrees east, another zone), not a swap: placed in the reference's zone
    _, q, _ = latlon_pair(ref, far, ("r.csv", "q.csv"))
    assert np.linalg.norm(q[0] - r[0]) > 100_000


def test_mixed_frames_is_one_sentence_with_a_hint():
    from seqnet.data.utm import mixed_frames

    said = mixed_frames("UTM zone 32V", "x, y metres of the positions files")
    assert said == ("the reference positions are metres in UTM zone 32V and the query positions x, y metres of the "
                    "positions files: positions in two frames do not compare; hint: give both positions files one "
                    "kind of positions (latitude / longitude in both, or easting / northing (x, y) metres of one "
                    "frame in both)")
    assert mixed_frames("degrees", "metres", "CSVs").startswith("the reference positions are latitude / longitude "
                                                                "degrees and the query positions easting / northing")
    assert "frame numbers in both" in mixed_frames("frames", "metres")
