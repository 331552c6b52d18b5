"""The live page in a real headless browser (Chromium): it loads, polls /v1/state with the token of its address's
fragment, and shows the route and each session's latest estimate; without the token it says so."""

from __future__ import annotations

import re
import shutil
import subprocess

import numpy as np
import pytest
from conftest import serving

from seqnet.client import Client
from seqnet.serve.page import CSP, PAGE

TOKEN = "page-test-token-0123456789abcdef"
BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def browser() -> str:
    found = next((shutil.which(b) for b in BROWSERS if shutil.which(b)), None)
    if found is None:
        pytest.skip(f"no headless browser found ({', '.join(BROWSERS)}): apt-get install chromium to run this test")
    return found


def rendered(url: str, *extra: str) -> str:
    """The page's DOM after its script ran (1.5 s of virtual time: two polls)."""
    p = subprocess.run([browser(), "--headless", "--no-sandbox", "--disable-gpu", "--virtual-time-budget=1500",
                        *extra, "--dump-dom", url], capture_output=True, text=True, timeout=90)
    assert p.returncode == 0, p.stderr[-2000:]
    return p.stdout


def test_the_page_holds_no_external_resource():
    assert not re.search(r"<script[^>]+src=|<link[^>]+href=|https?://(?!www\.w3\.org/2000/svg)", PAGE)
    assert "script-src 'sha256-" in CSP and "default-src 'none'" in CSP


def test_the_page_shows_the_route_and_the_sessions(serve_service, synth_dataset, tmp_path):
    q = synth_dataset.split("test").query.descriptors.astype(np.float32)
    with serving(serve_service, token=TOKEN) as (url, _):
        client = Client(url, TOKEN)
        sessions = [client.session() for _ in range(2)]
        last = [[s.send(f) for f in np.roll(q, 11 * i, axis=0)[:8]][-1] for i, s in enumerate(sessions)]
        dom = rendered(f"{url}/#token={TOKEN}", f"--screenshot={tmp_path / 'page.png'}", "--window-size=900,1000")
        locked = rendered(f"{url}/")
    assert '<span id="status">live</span>' in dom and '<span id="count">2</span>' in dom
    assert f"map ({serve_service.frames} frames)" in dom
    assert dom.count("<polyline") == 1
    for s, answer in zip(sessions, last, strict=True):
        row = re.search(rf'<tr class="session"><td[^>]*>{re.escape(s.id[:8])}</td><td>8</td><td>(\d+)</td>'
                        r"<td>([^<]*)</td>", dom)
        assert row and int(row[1]) == answer["estimate"] and row[2] == answer["estimate_name"], dom[-3000:]
        group = re.search(rf'<g fill="[^"]+" data-session="{re.escape(s.id)}">(.*?)</g>', dom)
        assert group and group[1].count("<circle") == sum(1 for a in s.answers if a["position"])
    assert "unauthorised" in locked and 'class="session"' not in locked
