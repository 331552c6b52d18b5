"""Positions from drive logs (Oxford RobotCar ins.csv, KITTI oxts), images matched by timestamp."""

from __future__ import annotations

import os

import numpy as np
import pytest
from conftest import mutated, read_mutated
from hypothesis import HealthCheck, given, settings
from PIL import Image

from seqnet.cli import main
from seqnet.cli.dataset_cmd.foreign import POSITIONS_FORMATS as CLI_FORMATS
from seqnet.core.errors import DatasetError, SeqnetError
from seqnet.data.gps import (
    POSITIONS_FORMATS,
    kitti_image_times,
    log_positions,
    parse_kitti_time,
    read_kitti_oxts,
    read_robotcar_ins,
)
from seqnet.data.io import load_dataset
from seqnet.data.utm import latlon_to_utm

# robotcar-dataset-sdk's ins.csv header
INS = ("timestamp,ins_status,latitude,longitude,altitude,northing,easting,down,utm_zone,velocity_north,"
       "velocity_east,velocity_down,roll,pitch,yaw")
T0 = 1418235223450115  # microseconds, as RobotCar's timestamps


def write_ins(path, n=50, t0=T0, east0=620000.0, step_us=20000):
    """ins.csv at 50 Hz along a line eastwards, 1 m per sample."""
    rows = [f"{t0 + i * step_us},INS_SOLUTION_GOOD,51.76,-1.26,110.5,5735000.0,{east0 + i:.3f},-110.5,30U,"
            "0.1,13.9,0.0,0.01,0.02,1.57" for i in range(n)]
    path.write_text(INS + "\n" + "\n".join(rows) + "\n")
    return path


def test_robotcar_ins_round_trip(tmp_path):
    log = read_robotcar_ins(write_ins(tmp_path / "ins.csv"))
    assert log.zone == "30U" and len(log.times) == 50
    assert log.times[1] - log.times[0] == pytest.approx(0.02) and log.positions[3].tolist() == [620003.0, 5735000.0]
    names = [f"{T0 + 20000 * 7 + 4000}.png", f"{T0 + 20000 * 2 - 9000}.png"]  # nearest: samples 7 and 2
    xy, unit, zone = log_positions("robotcar-ins", tmp_path / "ins.csv", names)
    assert xy[:, 0].tolist() == [620007.0, 620002.0] and (unit, zone) == ("metres", "30U")
    f = tmp_path / "ins.csv"  # without easting/northing, latitude/longitude (made metres with the other traverse's)
    f.write_text(f.read_text().replace("northing,easting", "north_m,east_m"))
    log = read_robotcar_ins(f)
    assert (log.unit, log.zone) == ("degrees", "?") and log.positions[0].tolist() == [51.76, -1.26]


def test_image_outside_the_log_is_refused_by_name(tmp_path):
    write_ins(tmp_path / "ins.csv")
    late = f"{T0 + 20000 * 49 + 500000}.png"  # half a second after the last sample
    with pytest.raises(DatasetError, match=rf"image '{late}' is 0.500 s from the nearest position sample"):
        log_positions("robotcar-ins", tmp_path / "ins.csv", [f"{T0}.png", late])
    assert log_positions("robotcar-ins", tmp_path / "ins.csv", [late], max_gap=0.6)[0][0, 0] == 620049.0
    with pytest.raises(DatasetError, match=r"image left.png: timestamp 'left' is not an integer"):
        log_positions("robotcar-ins", tmp_path / "ins.csv", ["left.png"])


def test_another_runs_log_is_named_and_max_time_gap_offered_only_for_small_misses(tmp_path):
    """Every image days outside the log (the query log of another run): the dates and 'another run's ins.csv?',
    never 'raise --max-time-gap' (which would place every image at the log's last sample); a small miss offers
    it with the value needed; a large one, or a gap inside the log, says where the images lie."""
    write_ins(tmp_path / "ins.csv")
    other_run = [f"{1422953110000000 + k * 62500}.png" for k in range(20)]
    with pytest.raises(DatasetError, match=r"no image lies within the log: the images are from 2015-02-03 08:45:10 "
                                           r"UTC, the log from 2014-12-10 .*; hint: another run's ins.csv\?") as err:
        log_positions("robotcar-ins", tmp_path / "ins.csv", other_run)
    assert "max-time-gap" not in str(err.value)
    late = f"{T0 + 20000 * 49 + 420000}.png"
    with pytest.raises(DatasetError, match=r"of these, 1 after its end; hint: trim the images to the log, or raise "
                                           r"--max-time-gap to 0.42 "):
        log_positions("robotcar-ins", tmp_path / "ins.csv", [f"{T0}.png", late])
    early = f"{T0 - 30_000_000}.png"  # 30 s before the log: trim, not a 30 s tolerance
    with pytest.raises(DatasetError, match=r"of these, 1 before the log's start; hint: trim the images to the "
                                           r"log$"):
        log_positions("robotcar-ins", tmp_path / "ins.csv", [early, f"{T0}.png"])
    f = tmp_path / "ins.csv"  # an INS outage: samples 10..39 missing
    f.write_text("\n".join(ln for i, ln in enumerate(f.read_text().splitlines()) if not 11 <= i <= 40) + "\n")
    with pytest.raises(DatasetError, match=r"of these, 1 in gaps of the log \(samples missing\); hint: leave out "
                                           r"the images in its gaps, or raise --max-time-gap to 0.3 "):
        log_positions("robotcar-ins", f, [f"{T0 + 20000 * 25}.png"])


def test_kitti_images_of_another_drive_are_named(tmp_path):
    drive = write_kitti_drive(tmp_path / "d")
    stamps = drive / "image_02" / "timestamps.txt"
    stamps.write_text(stamps.read_text().replace("2011-09-26", "2011-09-30"))
    with pytest.raises(DatasetError, match=r"the images are from 2011-09-30 13:02:25 UTC.*; hint: another "
                                           r"drive's oxts folder\?"):
        log_positions("kitti-oxts", drive / "oxts", ["image_02/data/0000000000.png"])


@pytest.mark.parametrize("edit, match", [
    (lambda t: t.replace(",620003.000,", ",east,"), r"line 5: easting/northing must be numbers"),
    (lambda t: t.replace(f"{T0 + 40000},", "soon,", 1), r"line 4: timestamp 'soon' is not an integer"),
    (lambda t: t.replace(",30U,", ",31U,", 1), r"2 UTM zones \(30U, 31U\)"),
    (lambda t: t.replace("timestamp,", "time,"), r"no column timestamp"),
])
def test_bad_ins_is_refused_with_the_line(tmp_path, edit, match):
    f = write_ins(tmp_path / "ins.csv")
    f.write_text(edit(f.read_text()))
    with pytest.raises(DatasetError, match=match):
        read_robotcar_ins(f)


def write_kitti_drive(root, n=6, lat0=49.011, lon0=8.4229, cam_offset_ns=3_000_000):
    """A KITTI raw drive folder: oxts/data/*.txt (30 values), oxts/timestamps.txt, image_02/timestamps.txt."""
    (root / "oxts" / "data").mkdir(parents=True)
    lines = []
    for i in range(n):
        vals = [lat0 + 1e-4 * i, lon0, 112.9, 0.02, -0.01, 1.5, *([0.5] * 19), 4, 10, 4, 4, 4]
        assert len(vals) == 30
        (root / "oxts" / "data" / f"{i:010d}.txt").write_text(" ".join(f"{v:.10g}" for v in vals) + "\n")
        lines.append(f"2011-09-26 13:02:{25 + i // 10}.{(i % 10) * 100_000_000 + 594_360:09d}")
    (root / "oxts" / "timestamps.txt").write_text("\n".join(lines) + "\n")
    (root / "image_02" / "data").mkdir(parents=True)
    cam = [f"2011-09-26 13:02:{25 + i // 10}.{(i % 10) * 100_000_000 + 594_360 + cam_offset_ns:09d}"
           for i in range(n)]
    (root / "image_02" / "timestamps.txt").write_text("\n".join(cam) + "\n")
    return root


def test_kitti_oxts_round_trip(tmp_path):
    drive = write_kitti_drive(tmp_path / "2011_09_26_drive_0001_sync")
    log = read_kitti_oxts(drive / "oxts")
    assert (log.unit, log.zone) == ("degrees", "?") and log.positions[3] == pytest.approx([49.011 + 3e-4, 8.4229])
    assert log.times[1] - log.times[0] == pytest.approx(0.1, abs=1e-6)
    assert parse_kitti_time("2011-09-26 13:02:25.594360375", "t") == pytest.approx(1317042145.594360375)
    names = ["image_02/data/0000000004.png", "image_02/data/0000000001.png"]
    latlon, unit, _ = log_positions("kitti-oxts", drive / "oxts", names)  # names relative to the drive folder
    assert unit == "degrees" and latlon[0] == pytest.approx(log.positions[4]) and latlon[1] == pytest.approx(
        log.positions[1])


def test_kitti_ragged_and_missing_inputs_are_refused(tmp_path):
    drive = write_kitti_drive(tmp_path / "d")
    with pytest.raises(DatasetError, match=r"0000000009.png is not a frame number within the 6 lines"):
        kitti_image_times([drive / "image_02" / "data" / "0000000009.png"])
    with pytest.raises(DatasetError, match=r"KITTI timestamps file not found: .*image_03"):
        kitti_image_times([drive / "image_03" / "data" / "0000000000.png"])
    f = drive / "oxts" / "data" / "0000000002.txt"
    f.write_text(" ".join(f.read_text().split()[:29]))
    with pytest.raises(DatasetError, match=r"0000000002.txt: 29 values, a KITTI oxts file has 30"):
        read_kitti_oxts(drive)
    stamps = drive / "oxts" / "timestamps.txt"
    stamps.write_text("\n".join(stamps.read_text().splitlines()[:5]) + "\n")
    with pytest.raises(DatasetError, match=r"5 lines in timestamps.txt for 6 data/\*.txt files"):
        read_kitti_oxts(drive)
    stamps.write_text("26/09/2011 13:02\n" * 6)
    with pytest.raises(DatasetError, match=r"timestamps.txt, line 1: '26/09/2011 13:02' is not a KITTI timestamp"):
        read_kitti_oxts(drive)
    with pytest.raises(DatasetError, match=r"sample 1: latitude 91.0"):
        latlon_to_utm(np.array([49.0, 91.0]), np.array([8.4, 8.4]), "gps")


def test_from_csv_with_kitti_logs(tmp_path):
    ref = write_kitti_drive(tmp_path / "ref")
    qry = write_kitti_drive(tmp_path / "qry", lat0=49.011 + 2e-5)  # about 2 m north of the reference
    names = "\n".join(f"image_02/data/{i:010d}.png" for i in range(6))
    for d in (ref, qry):
        np.save(d / "desc.npy", np.eye(6, 4, dtype=np.float32) + 0.5)
        (d / "names.txt").write_text(names)
    out = tmp_path / "ds"
    assert main(["-q", "dataset", "from-csv", "--positions-format", "kitti-oxts", "--ref-csv", str(ref / "oxts"),
                 "--ref-desc", str(ref / "desc.npy"), "--ref-names", str(ref / "names.txt"),
                 "--query-csv", str(qry / "oxts"), "--query-desc", str(qry / "desc.npy"),
                 "--query-names", str(qry / "names.txt"), "--radius", "5", "--out", str(out)]) == 0
    ds = load_dataset(out)
    d = np.linalg.norm(ds.query.positions - ds.reference.positions, axis=1)
    assert ds.position_unit == "metres" and np.allclose(d, 2.22, atol=0.05)
    assert ds.extra["positions_frame"] == "UTM zone 32U"  # for localize --positions-topic


def test_from_images_with_robotcar_ins(tmp_path, capsys):
    rng = np.random.default_rng(0)
    for side, t0 in (("ref", T0), ("qry", T0 + 10**9)):
        (tmp_path / side).mkdir()
        write_ins(tmp_path / f"{side}_ins.csv", t0=t0, east0=620000.0 + (0.5 if side == "qry" else 0))
        for i in range(0, 40, 4):
            img = rng.integers(0, 256, size=(16, 32, 3), dtype=np.uint8)
            Image.fromarray(img).save(tmp_path / side / f"{t0 + 20000 * i + 1000}.png")
    out = tmp_path / "ds"
    argv = ["-q", "dataset", "from-images", str(tmp_path / "ref"), str(tmp_path / "qry"), "--method", "pixels",
            "--patch", "0", "--positions-format", "robotcar-ins", "--ref-csv", str(tmp_path / "ref_ins.csv"),
            "--query-csv", str(tmp_path / "qry_ins.csv"), "--radius", "2", "--out", str(out)]
    assert main(argv) == 0
    ds = load_dataset(out)
    assert ds.reference.positions[:, 0].tolist() == [620000.0 + i for i in range(0, 40, 4)]
    assert ds.query.positions[:, 0].tolist() == [620000.5 + i for i in range(0, 40, 4)]
    assert ds.extra["positions_frame"].startswith("UTM zone ")
    Image.fromarray(np.zeros((16, 32, 3), np.uint8)).save(tmp_path / "qry" / f"{T0 + 10**9 + 5 * 10**6}.png")
    assert main([*argv[:-1], str(tmp_path / "ds2")]) == 2
    assert f"image '{T0 + 10**9 + 5 * 10**6}.png' is 4.020 s from the nearest" in capsys.readouterr().err


def test_the_cli_offers_the_formats_of_the_table():
    assert CLI_FORMATS == POSITIONS_FORMATS


@pytest.mark.parametrize("edit, match", [
    (lambda t: t.replace(str(T0 + 40000), "9" * 400, 1), r"line 4: timestamp '9{57}'\.\.\. is not an integer"),
    (lambda t: t.replace(str(T0 + 40000), "²", 1), r"line 4: timestamp '²' is not an integer"),
    (lambda t: t.replace(",620003.000,", ",nan,"), r"line 5: easting/northing must be numbers \(finite\), got "
                                                  r"'nan', '5735000.0'"),
    (lambda t: t.replace(",620003.000,", ",1e999,"), r"line 5: easting/northing must be numbers \(finite\), "
                                                    r"got .1e999."),
    (lambda t: t.replace(",30U,", ",30U\x1b]0;owned\x07,", 1), r"line 2: utm_zone '30U\\x1b\]0;owned\\x07' is not a "
                                                            r"UTM zone"),
])
def test_hostile_ins_values_are_refused_by_line(tmp_path, edit, match):
    """400-digit timestamps (an OverflowError before), digits that int() refuses, NaN / inf positions and a UTM
    zone holding terminal escapes: one line each, the value shown escaped."""
    f = write_ins(tmp_path / "ins.csv")
    f.write_text(edit(f.read_text()))
    with pytest.raises(DatasetError, match=match):
        read_robotcar_ins(f)


def test_hostile_image_names_for_robotcar(tmp_path):
    write_ins(tmp_path / "ins.csv")
    for name in ("9" * 400 + ".png", "²³.png", "-5.png"):
        with pytest.raises(DatasetError, match=r"is not an integer \(microseconds"):
            log_positions("robotcar-ins", tmp_path / "ins.csv", [name])


def test_kitti_hostile_files_and_names(tmp_path):
    """A data file named ²: an error, not int()'s ValueError; a FIFO among the oxts files: refused, not waited
    on; an image name leading out of the drive folder: its timestamps.txt is never read."""
    drive = write_kitti_drive(tmp_path / "d")
    (drive / "oxts" / "data" / "².txt").write_text((drive / "oxts" / "data" / "0000000000.txt").read_text())
    (drive / "oxts" / "data" / "0000000005.txt").unlink()
    with pytest.raises(DatasetError, match=r": ²\.txt is not a frame number"):
        read_kitti_oxts(drive)
    (drive / "oxts" / "data" / "².txt").unlink()
    os.mkfifo(drive / "oxts" / "data" / "0000000005.txt")
    with pytest.raises(DatasetError, match=r"0000000005\.txt is a FIFO \(named pipe\), not a regular file"):
        read_kitti_oxts(drive)
    outside = write_kitti_drive(tmp_path / "elsewhere")
    assert kitti_image_times([outside / "image_02" / "data" / "0000000001.png"])[0] > 0  # a file the user names
    inner = write_kitti_drive(tmp_path / "drive")
    for name in ("../elsewhere/image_02/data/0000000001.png", "0000000001.png"):
        with pytest.raises(DatasetError, match=r"KITTI timestamps: '\.\./.*timestamps\.txt' leads outside"):
            log_positions("kitti-oxts", inner / "oxts", ["image_02/data/0000000000.png", name])


def test_kitti_timestamps_fifo_is_refused(tmp_path):
    drive = write_kitti_drive(tmp_path / "d")
    (drive / "image_02" / "timestamps.txt").unlink()
    os.mkfifo(drive / "image_02" / "timestamps.txt")
    with pytest.raises(DatasetError, match=r"is a FIFO"):
        log_positions("kitti-oxts", drive / "oxts", ["image_02/data/0000000000.png"])


INS_VALID = (INS + "\n" + "\n".join(f"{T0 + i * 20000},G,51.76,-1.26,110.5,5735000.0,{620000 + i}.0,-1,30U,0,0,0,0,0,0"
                                    for i in range(4)) + "\n").encode()
OXTS_VALID = (" ".join(["49.011", "8.4229", *["0.5"] * 28]) + "\n").encode()
STAMPS_VALID = b"2011-09-26 13:02:25.594360375\n2011-09-26 13:02:25.694360375\n"


@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
@given(data=mutated(INS_VALID))
def test_fuzzed_ins_gives_samples_or_one_error(tmp_path, data):
    log = read_mutated(read_robotcar_ins, tmp_path / "ins.csv", data, SeqnetError)
    assert log is None or np.isfinite(log.positions).all() and np.isfinite(log.times).all()


@settings(max_examples=100, deadline=None, suppress_health_check=list(HealthCheck))
@given(oxts=mutated(OXTS_VALID), stamps=mutated(STAMPS_VALID))
def test_fuzzed_kitti_drive_gives_samples_or_one_error(tmp_path, oxts, stamps):
    d = tmp_path / "oxts"
    (d / "data").mkdir(parents=True, exist_ok=True)
    (d / "data" / "0000000000.txt").write_bytes(oxts)
    (d / "data" / "0000000001.txt").write_bytes(OXTS_VALID)
    (d / "timestamps.txt").write_bytes(stamps)
    try:
        log = read_kitti_oxts(d)
    except SeqnetError:
        return
    assert np.isfinite(log.positions).all() and np.isfinite(log.times).all()
