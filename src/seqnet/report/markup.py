"""The HTML pieces of the report: :class:`Section`, embedded PNGs (:func:`png_tag`), escaped tables
(:func:`table_html`, sortable by the page's own inline script :data:`SORT_JS`)."""

from __future__ import annotations

import base64
import dataclasses
import html
from collections.abc import Sequence
from typing import Any


@dataclasses.dataclass
class Section:
    """One section of the report: an ``id`` (anchor), a title and its HTML body."""

    id: str
    title: str
    body: str


def png_tag(png: bytes, alt: str) -> str:
    """An ``<img>`` whose source is the PNG itself (a base64 data URI)."""
    data = base64.b64encode(png).decode("ascii")
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{data}">'


def table_html(header: Sequence[str] | None, rows: Sequence[Sequence[Any]], sortable: bool = False) -> str:
    """An HTML table (cells escaped; ``header`` None: none); ``sortable``: a click on a column's heading sorts the
    rows by it (numbers as numbers; again: the other way), by the page's own script (:data:`SORT_JS`)."""
    header = header if header and any(str(h) for h in header) else None  # all blank: no header row
    head = "" if header is None else \
        "<thead><tr>" + "".join(f"<th>{html.escape(str(h))}</th>" for h in header) + "</tr></thead>"
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows)
    cls = ' class="sortable"' if sortable else ' class="facts"' if header is None else ""
    return f"<table{cls}>{head}<tbody>{body}</tbody></table>"


# sorts a table.sortable by the clicked column: numbers numerically (a dash or empty cell last), text
# alphabetically; a second click reverses. Inline: the report stays one file that loads nothing.
SORT_JS = """document.querySelectorAll("table.sortable th").forEach(function(th,col){th.title="click to sort";
th.addEventListener("click",function(){var tb=th.closest("table").tBodies[0],rows=Array.from(tb.rows),
up=th.dataset.dir!=="asc";th.closest("tr").querySelectorAll("th").forEach(function(h){h.dataset.dir="";
h.classList.remove("asc","desc")});th.dataset.dir=up?"asc":"desc";th.classList.add(up?"asc":"desc");
function key(r){var t=r.cells[col].textContent.trim(),n=parseFloat(t);return isNaN(n)?t:n}
rows.sort(function(a,b){var x=key(a),y=key(b),nx=typeof x==="number",ny=typeof y==="number";
if(nx!==ny)return nx?-1:1;var c=nx?x-y:String(x).localeCompare(String(y));return up?c:-c});
rows.forEach(function(r){tb.appendChild(r)})})});"""
