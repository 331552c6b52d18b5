"""``seqnet localize --map MAP --query RUN.bag --topic T``: frames streamed from a bag (ROS 1, ROS 2, MCAP)."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from conftest import BAG_KINDS, bag_path, drive, write_bag
from PIL import Image

from seqnet.cli import main as cli_main

pytest.importorskip("rosbags", reason="rosbags is not installed (pip install 'seqnet[ros]')")
TOPIC, START, PERIOD = "/camera/image_raw", 10**18, 10**8


@pytest.mark.parametrize("kind", BAG_KINDS)
def test_a_bag_is_localised_end_to_end_as_its_images_are(tmp_path, kind, capsys):
    ref_dir, qry_dir = tmp_path / "ref", tmp_path / "qry"
    for d, images in ((ref_dir, drive(30, 1)), (qry_dir, drive(30, 2, noise=40)[5:25])):
        d.mkdir()
        for i, im in enumerate(images):
            Image.fromarray(im).save(d / f"{i:03d}.png")
    shift = np.arange(20)[:, None] + 5  # query frame i shows reference place i + 5
    ds = tmp_path / "map"
    (tmp_path / "pos.json").write_text(json.dumps(shift.tolist()))
    assert cli_main(["-q", "dataset", "from-images", str(ref_dir), str(qry_dir), "--positives",
                     str(tmp_path / "pos.json"), "--method", "pixels", "--patch", "4", "--out", str(ds),
                     "--device", "cpu"]) == 0
    bag = write_bag(bag_path(tmp_path, kind), drive(30, 2, noise=40)[5:25], kind, start=START, period=PERIOD)
    tracks = {}
    for name, query in (("bag", [str(bag), "--topic", TOPIC]), ("folder", [str(qry_dir)])):
        out = tmp_path / f"{name}.csv"
        assert cli_main(["-q", "localize", "--map", str(ds), "--query", *query, "--method", "raw+seqmatch",
                         "--seq-len", "3", "--out", str(out), "--device", "cpu"]) == 0
        tracks[name] = list(csv.DictReader(out.open()))
    assert "ms per image" in capsys.readouterr().out
    bag_rows, folder_rows = tracks["bag"], tracks["folder"]
    assert len(bag_rows) == 20 and [r["name"] for r in bag_rows] == [str(START + i * PERIOD) for i in range(20)]
    for key in ("estimate", "score", "confidence", "full_window"):
        assert [r[key] for r in bag_rows] == [r[key] for r in folder_rows]
    full = [int(r["estimate"]) for r in bag_rows if r["full_window"] == "1"]
    assert full == list(range(7, 25))  # the places the frames show: localised by the bag's own frames
    summary = json.loads((tmp_path / "bag.json").read_text())
    assert summary["inputs"]["topic"] == TOPIC and summary["summary"]["frames"] == 20


def test_bag_query_refusals(tmp_path, synth_dir, capsys):
    bag = write_bag(tmp_path / "q.bag", drive(3, 1), fixes=[(63.4, 10.4, 0)] * 3)
    base = ["localize", "--map", str(synth_dir), "--method", "single", "--out", str(tmp_path / "t.csv")]
    cases = [(["--query", str(bag)], "name its image topic with --topic (its image topics: /camera/image_raw"),
             (["--query", str(bag), "--topic", "/gps/fix"], "carries sensor_msgs/msg/NavSatFix, not an image"),
             (["--query", str(bag), "--topic", "/none"], "has no topic '/none'; its topics: /camera/image_raw"),
             (["--topic", TOPIC], "--topic names the image topic of a ROS bag given as --query")]
    for args, msg in cases:
        assert cli_main([*base, *args]) == 2
        err = capsys.readouterr().err
        assert msg in err and "Traceback" not in err, err
