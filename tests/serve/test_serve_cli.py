"""``seqnet serve``: refusals before any work, answers equal ``seqnet localize``, SIGTERM drains and exits 0."""

from __future__ import annotations

import csv
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from conftest import REPO, SERVE_METHOD

from seqnet.cli import main as cli
from seqnet.client import Client, ClientError
from seqnet.core.errors import ConfigError
from seqnet.serve.settings import ServeSettings, read_token


def one_line_error(capsys, argv, needle, code=2):
    assert cli(argv) == code
    err = capsys.readouterr().err.strip()
    assert needle in err and len(err.splitlines()) == 1, err


def test_refusals_before_the_map_is_read(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("SEQNET_TOKEN", raising=False)
    base = ["serve", "--map", str(tmp_path / "no-such-map")]
    one_line_error(capsys, base, "refuses to start without a token")
    monkeypatch.setenv("SEQNET_TOKEN", "  ")
    one_line_error(capsys, base, "refuses to start without a token")  # an empty token is no token
    (tmp_path / "empty").write_text("\n")
    one_line_error(capsys, [*base, "--token-file", str(tmp_path / "empty")], "without a token")
    one_line_error(capsys, [*base, "--no-auth", "--host", "0.0.0.0"], "--no-auth serves on 127.0.0.1")
    one_line_error(capsys, [*base, "--token-file", str(tmp_path / "missing")], "token file not found")
    monkeypatch.setenv("SEQNET_TOKEN", "a-token-long-enough-to-pass")
    one_line_error(capsys, [*base, "--no-auth"], "contradict")
    one_line_error(capsys, [*base, "--top-k", "3", "--method", "single"], "--top-k is")
    one_line_error(capsys, base, "no-such-map")  # only now is the map read


def test_tokens_and_settings():
    assert read_token(None, {"SEQNET_TOKEN": " abc-def-ghi-jkl-mno \n"}) == "abc-def-ghi-jkl-mno"
    assert read_token(None, {"SEQNET_TOKEN": ""}) is None and read_token(None, {}) is None
    with pytest.raises(ConfigError, match="printable ASCII"):
        read_token(None, {"SEQNET_TOKEN": "two words"})
    assert ServeSettings(host="::1", no_auth=True).token is None
    assert "tok" not in repr(ServeSettings(token="tok-secret"))
    with pytest.raises(ConfigError, match="session_idle_s"):
        ServeSettings(no_auth=True, session_idle_s=0)


def test_a_port_in_use_is_one_line(serve_map, capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        one_line_error(capsys, ["serve", "--map", str(serve_map), "--method", SERVE_METHOD, "--no-auth", "--port",
                                str(s.getsockname()[1]), "--device", "cpu"], "ddress")


def start(serve_map, env):
    p = subprocess.Popen([sys.executable, "-m", "seqnet", "serve", "--map", str(serve_map), "--method", SERVE_METHOD,
                          "--port", "0", "--device", "cpu"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         env={**os.environ, "PYTHONPATH": str(REPO / "src"), **env})
    line = p.stdout.readline()
    if "serving" not in line:
        p.kill()
        pytest.fail(f"seqnet serve did not start: {line!r} {p.stderr.read()!r}")
    return p, re.search(r"http://[^\s;]+/", line)[0]


def test_served_answers_equal_localize_and_sigterm_drains(serve_map, synth_dataset, tmp_path):
    q = synth_dataset.split("test").query.descriptors[:20].astype(np.float32)
    np.save(tmp_path / "q.npy", q)
    assert cli(["-q", "localize", "--map", str(serve_map), "--query", str(tmp_path / "q.npy"), "--method",
                SERVE_METHOD, "--device", "cpu", "--out", str(tmp_path / "t.csv")]) == 0
    track = list(csv.DictReader((tmp_path / "t.csv").open()))
    token = "token-of-the-subprocess-test-0123"
    p, url = start(serve_map, {"SEQNET_TOKEN": token})
    try:
        with pytest.raises(ClientError) as e:
            Client(url, "wrong").session()
        assert e.value.status == 401
        answers = list(Client(url, token).localize(q))
        assert [a["estimate"] if a["estimate"] is not None else -1 for a in answers] == \
               [int(r["estimate"]) for r in track]
        assert [a["estimate_name"] or "" for a in answers] == [r["estimate_name"] for r in track]
        assert [f"{a['confidence']:.6f}" for a in answers] == [r["confidence"] for r in track]
        statuses, stop = [], threading.Event()

        def load():  # frames in flight while SIGTERM arrives
            s = Client(url, token).session()
            while not stop.is_set():
                try:
                    s.send(q[len(statuses) % len(q)])
                    statuses.append(200)
                except ClientError as err:
                    statuses.append(err.status)
                    return

        t = threading.Thread(target=load)
        t.start()
        time.sleep(0.3)
        t0 = time.monotonic()
        p.send_signal(signal.SIGTERM)
        out, err = p.communicate(timeout=30)
        stopped_in = time.monotonic() - t0
        stop.set()
        t.join(10)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0, err
    assert "stopped:" in out and "Traceback" not in err
    assert statuses and all(s in (200, 0) for s in statuses), statuses  # answered, or refused a connection
    assert stopped_in < 10, stopped_in


def test_serving_switches_threads_often_and_restores_the_interval(serve_service):
    """While serve() runs the GIL's switch interval is SWITCH_S (the event loop is not kept waiting 5 ms by the
    localising threads); once it returns, the interval is what it was."""
    from seqnet.serve.server import SWITCH_S, serve

    before, seen = sys.getswitchinterval(), []

    def started(port: int) -> None:
        seen.append(sys.getswitchinterval())
        os.kill(os.getpid(), signal.SIGTERM)  # a normal stop: serve() returns

    stats = serve(serve_service, ServeSettings(port=0, no_auth=True), started)
    assert seen == [SWITCH_S] and SWITCH_S < before
    assert sys.getswitchinterval() == before and stats["frames"] == 0
