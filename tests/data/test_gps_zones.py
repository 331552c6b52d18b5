"""Drive logs on either side of a UTM zone boundary (seqnet.data.gps): latitude / longitude are placed in the
reference's zone, as a positions CSV's; logged easting / northing in two zones are refused with the way out."""

from __future__ import annotations

import numpy as np
import pytest
import utm
from PIL import Image
from test_gps import INS, T0

from seqnet.cli import main
from seqnet.core.errors import DatasetError
from seqnet.data.gps import read_robotcar_ins
from seqnet.data.io import load_dataset

# RobotCar's gps/gps.csv (the columns the robotcar-dataset-sdk users read: easting 9, northing 8, utm_zone 11)
GPS = ("timestamp,num_satellites,latitude,longitude,altitude,latitude_sigma,longitude_sigma,altitude_sigma,northing,"
       "easting,down,utm_zone")
LAT, LON0, STEP = 60.0, 11.999, 5e-5  # eastwards along 60 N across 12 E (zones 32V | 33V), about 2.8 m a step
RENAMED = "northing_utm,easting_utm"  # the hint's way out: easting / northing columns renamed, lat / lon read


def lonlat(k: int) -> tuple[float, float]:
    return LAT, LON0 + STEP * k


def write_gps(path, steps, t0=T0, zone=None, header=GPS):
    """gps.csv at 50 Hz along ``steps``; easting / northing in ``zone`` (number, letter), else in each sample's own
    zone (as a receiver logs them: the zone changes at 12 E)."""
    rows = []
    for i, k in enumerate(steps):
        lat, lon = lonlat(k)
        e, n, num, let = utm.from_latlon(lat, lon, *(zone or (None, None)))
        rows.append(f"{t0 + 20000 * i},9,{lat:.8f},{lon:.8f},110.5,0.5,0.5,0.8,{n:.3f},{e:.3f},-110.5,{num}{let}")
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    return path


def renamed(path):
    path.write_text(path.read_text().replace("northing,easting", RENAMED, 1))
    return path


def from_csv(tmp_path, out, ref_log, qry_log, n_ref=40, first_q=21):
    rng = np.random.default_rng(0)
    d = rng.normal(size=(n_ref, 8)).astype(np.float32)
    for side, desc, t0 in (("ref", d, T0), ("qry", d[first_q:] + 0.01, T0 + 10**9)):
        np.save(tmp_path / f"{side}.npy", desc)
        (tmp_path / f"{side}.txt").write_text("".join(f"{t0 + 20000 * i}.png\n" for i in range(len(desc))))
    return main(["-q", "dataset", "from-csv", "--positions-format", "robotcar-ins", "--ref-csv", str(ref_log),
                 "--ref-desc", str(tmp_path / "ref.npy"), "--ref-names", str(tmp_path / "ref.txt"),
                 "--query-csv", str(qry_log), "--query-desc", str(tmp_path / "qry.npy"),
                 "--query-names", str(tmp_path / "qry.txt"), "--radius", "5", "--out", str(out)])


def test_easting_northing_in_two_zones_are_refused_with_the_way_out_which_works(tmp_path, capsys):
    """The reference logged in 32V (beyond 12 E too), the query (its eastern half) in 33V: their metres are ~400 km
    apart; refused, with the hint to read latitude / longitude instead; done so, the query is placed in the
    reference's zone, each query image on its reference image (the same lat / lon)."""
    ref = write_gps(tmp_path / "ref_gps.csv", range(40), zone=(32, "V"))
    qry = write_gps(tmp_path / "qry_gps.csv", range(21, 40), t0=T0 + 10**9)
    assert from_csv(tmp_path, tmp_path / "ds", ref, qry) == 2
    err = capsys.readouterr().err
    assert "reference positions are in UTM zone 32V, query positions in 33V; positions in two zones are not " \
           "comparable; hint: a log without easting, northing columns is read by its latitude, longitude, placed " \
           "in the reference's zone: rename those two columns in the logs' headers" in err
    assert from_csv(tmp_path, tmp_path / "ds", renamed(ref), renamed(qry)) == 0
    ds = load_dataset(tmp_path / "ds")
    assert ds.extra["positions_frame"] == "UTM zone 32V" and ds.position_unit == "metres"
    assert np.abs(ds.query.positions - ds.reference.positions[21:]).max() < 1e-6
    assert np.linalg.norm(ds.reference.positions[21] - ds.reference.positions[20]) == pytest.approx(2.79, abs=0.01)


def test_a_log_whose_zone_changes_mid_drive_is_refused_with_the_way_out(tmp_path):
    """A drive across 12 E logged by a receiver: its easting jumps by ~400 km where utm_zone turns 33V; refused,
    with the hint; with the easting / northing columns renamed its latitude / longitude are read (utm_zone
    left as it is)."""
    f = write_gps(tmp_path / "gps.csv", range(40))
    with pytest.raises(DatasetError, match=r"gps.csv: easting/northing in 2 UTM zones \(32V, 33V\), which do not "
                                           r"compare; hint: a log without easting, northing columns is read by "
                                           r"its latitude, longitude"):
        read_robotcar_ins(f)
    log = read_robotcar_ins(renamed(f))
    assert (log.unit, log.zone) == ("degrees", "?") and log.positions[39] == pytest.approx(lonlat(39))


def test_from_images_with_logs_either_side_of_the_boundary(tmp_path, capsys):
    """from-images reads the logs as from-csv does: lat / lon (ins.csv with its easting / northing renamed), the
    query (east of 12 E only) in the reference's zone (before: refused, 'UTM zone UTM zone 32V'); easting /
    northing in two zones: refused with the way out."""
    rng = np.random.default_rng(0)
    for side, t0, steps in (("ref", T0, range(40)), ("qry", T0 + 10**9, range(21, 40))):
        (tmp_path / side).mkdir()
        rows = [f"{t0 + 20000 * i},INS_SOLUTION_GOOD,{lonlat(k)[0]:.8f},{lonlat(k)[1]:.8f},110.5,0,0,-110.5,"
                f"{utm.from_latlon(*lonlat(k))[2]}V,0,0,0,0,0,0" for i, k in enumerate(steps)]
        (tmp_path / f"{side}_ins.csv").write_text(INS.replace("northing,easting", RENAMED) + "\n" + "\n".join(rows))
        for i in range(0, len(steps), 2):
            img = rng.integers(0, 256, size=(16, 32, 3), dtype=np.uint8)
            Image.fromarray(img).save(tmp_path / side / f"{t0 + 20000 * i + 1000}.png")
    argv = ["-q", "dataset", "from-images", str(tmp_path / "ref"), str(tmp_path / "qry"), "--method", "pixels",
            "--patch", "0", "--positions-format", "robotcar-ins", "--ref-csv", str(tmp_path / "ref_ins.csv"),
            "--query-csv", str(tmp_path / "qry_ins.csv"), "--radius", "5", "--out", str(tmp_path / "ds")]
    assert main(argv) == 0
    ds = load_dataset(tmp_path / "ds")
    assert ds.extra["positions_frame"] == "UTM zone 32V"
    want = np.array([utm.from_latlon(*lonlat(k), 32, "V")[:2] for k in range(21, 40, 2)])
    assert np.abs(ds.query.positions - want).max() < 1e-6
    write_gps(tmp_path / "ref_ins.csv", range(40), zone=(32, "V"))
    write_gps(tmp_path / "qry_ins.csv", range(21, 40), t0=T0 + 10**9)
    assert main([*argv[:-1], str(tmp_path / "ds2")]) == 2
    assert "positions in two zones are not comparable; hint: a log without easting, northing" in capsys.readouterr().err
