"""``localize --map`` / ``serve --map`` without ``--method`` run the index map's own method (the one ``seqnet index
build`` made it for), said in one line, instead of asking for ``hvpr`` and being refused."""

from __future__ import annotations

import csv
from pathlib import Path

from conftest import SERVE_METHOD

from seqnet.cli import build_parser, main


def test_localize_on_an_index_map_without_method_runs_the_maps_own(serve_map, tmp_path, capsys):
    query = Path(serve_map).parent / "ds" / "query" / "descriptors.npy"
    out = tmp_path / "t.csv"
    assert main(["--threads", "1", "localize", "--map", str(serve_map), "--query", str(query), "--out", str(out)]) == 0
    cap = capsys.readouterr()
    said = [line for line in cap.err.splitlines() if "--method not given" in line]
    assert said == [f"--method not given: {SERVE_METHOD}, the method map {serve_map} was built for"], cap.err
    assert cap.out.startswith(f"{SERVE_METHOD}: ") and any(r["estimate"] != "-1" for r in csv.DictReader(out.open()))
    out.unlink()
    assert main(["--threads", "1", "localize", "--map", str(serve_map), "--query", str(query), "--method",
                 SERVE_METHOD, "--out", str(out)]) == 0
    assert "--method not given" not in capsys.readouterr().err  # given: nothing said


def test_serve_takes_the_maps_method_and_a_dataset_keeps_the_default(serve_map):
    from seqnet.cli.localize_cmd import localizer_config

    args = build_parser(["serve"]).parse_args(["serve", "--map", str(serve_map), "--no-auth"])
    assert localizer_config(args).method == SERVE_METHOD
    args = build_parser(["serve"]).parse_args(["serve", "--map", str(Path(serve_map).parent / "ds"), "--no-auth"])
    assert localizer_config(args).method == "hvpr"  # a dataset directory runs every method: the default
