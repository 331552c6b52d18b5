"""``GET /``: the live page. One self-contained HTML document (inline style and script, no external resource,
pinned by its Content-Security-Policy) that polls ``GET /v1/state`` every second and draws the route (the map's
reference positions) and each session's latest estimates on it, with a table of the sessions.

The page holds no data itself; ``/v1/state`` needs the token like every other route but ``/health``. The page
reads it from the address's fragment (``http://host:port/#token=TOKEN``), which browsers never send to a server
or put in a Referer; names from the map's files are shown as text, never parsed as HTML.
"""

from __future__ import annotations

import base64
import hashlib

SCRIPT = r"""
const token = new URLSearchParams(location.hash.slice(1)).get("token");
const headers = token ? {Authorization: "Bearer " + token} : {};
const colours = ["#d62728", "#1f77b4", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf"];
const svgNS = "http://www.w3.org/2000/svg";
function el(tag, attrs, text) {
  const e = tag === "svg" || ["polyline", "circle", "g"].includes(tag) ? document.createElementNS(svgNS, tag)
                                                                        : document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
  if (text !== undefined) e.textContent = text;
  return e;
}
function scaler(route) {
  const xs = route.map(p => p[0]), ys = route.map(p => p[1]);
  const x0 = Math.min(...xs), x1 = Math.max(...xs), y0 = Math.min(...ys), y1 = Math.max(...ys);
  const s = 560 / Math.max(x1 - x0, y1 - y0, 1e-9);  // one scale for both axes, the route centred
  const dx = (560 - (x1 - x0) * s) / 2, dy = (560 - (y1 - y0) * s) / 2;
  return p => [20 + dx + (p[0] - x0) * s, 580 - dy - (p[1] - y0) * s];
}
function draw(state) {
  document.getElementById("map").textContent = state.map + " (" + state.frames + " frames)";
  const svg = document.getElementById("route");
  svg.replaceChildren();
  const rows = document.getElementById("sessions");
  rows.replaceChildren();
  const at = state.route && state.route.length ? scaler(state.route) : null;
  if (at) svg.appendChild(el("polyline", {points: state.route.map(p => at(p).join(",")).join(" "),
                                          fill: "none", stroke: "#999", "stroke-width": 2}));
  state.sessions.forEach((s, i) => {
    const colour = colours[i % colours.length], last = s.latest[s.latest.length - 1];
    const g = el("g", {fill: colour, "data-session": s.session});
    if (at) s.latest.filter(a => a.position).forEach((a, j, all) =>
      g.appendChild(el("circle", {cx: at(a.position)[0], cy: at(a.position)[1], r: j === all.length - 1 ? 7 : 3,
                                  opacity: j === all.length - 1 ? 1 : 0.4})));
    svg.appendChild(g);
    const tr = el("tr", {"class": "session"});
    const cells = [s.session.slice(0, 8), s.frames, last ? (last.estimate ?? "-") : "-",
                   last ? (last.estimate_name ?? "-") : "-", last ? last.confidence.toFixed(3) : "-",
                   last ? last.latency_ms.toFixed(1) : "-", s.idle_s];
    cells.forEach((c, j) => tr.appendChild(el("td", j === 0 ? {style: "color:" + colour} : {}, String(c))));
    rows.appendChild(tr);
  });
  document.getElementById("count").textContent = state.sessions.length;
}
async function poll() {
  const status = document.getElementById("status");
  try {
    const r = await fetch("/v1/state", {headers, cache: "no-store"});
    if (r.status === 401) status.textContent = "unauthorised: open this page as /#token=YOUR_TOKEN";
    else if (!r.ok) status.textContent = "error " + r.status;
    else { draw(await r.json()); status.textContent = "live"; }
  } catch (e) { status.textContent = "server unreachable"; }
  setTimeout(poll, 1000);
}
poll();
"""

STYLE = """
body { font-family: sans-serif; margin: 1.5em; color: #222; }
#route { border: 1px solid #ccc; background: #fafafa; }
table { border-collapse: collapse; margin-top: 1em; } td, th { padding: 2px 10px; border-bottom: 1px solid #ddd; }
#status { font-weight: bold; }
"""


def script_hash() -> str:
    """The CSP source of the inline script (``'sha256-…'``): the only script the page may run."""
    return "'sha256-" + base64.b64encode(hashlib.sha256(SCRIPT.encode()).digest()).decode() + "'"


CSP = (f"default-src 'none'; script-src {script_hash()}; style-src 'unsafe-inline'; connect-src 'self'; "
       "base-uri 'none'; form-action 'none'; frame-ancestors 'none'")

PAGE = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>seqnet serve</title><style>{STYLE}</style></head>
<body>
<h1>seqnet serve</h1>
<p>map: <span id="map">…</span> · sessions: <span id="count">0</span> · <span id="status">connecting</span></p>
<svg id="route" xmlns="http://www.w3.org/2000/svg" width="600" height="600" viewBox="0 0 600 600"></svg>
<table><thead><tr><th>session</th><th>frames</th><th>estimate</th><th>name</th><th>confidence</th>
<th>latency (ms)</th><th>idle (s)</th></tr></thead><tbody id="sessions"></tbody></table>
<script>{SCRIPT}</script>
</body></html>
"""

HEADERS = {"Content-Security-Policy": CSP, "X-Content-Type-Options": "nosniff", "Referrer-Policy": "no-referrer",
           "Cache-Control": "no-store"}
