"""HTML pieces of the report: escaping, numbers with ``data-key`` / ``data-value``, tables, images."""

from __future__ import annotations

import base64
import html
from pathlib import Path
from typing import Any

import numpy as np

CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222;line-height:1.45}
h1{margin-bottom:.2em}h2{border-bottom:2px solid #ddd;padding-bottom:.2em;margin-top:2em}h3{margin-bottom:.3em}
table{border-collapse:collapse;margin:.6em 0 1.2em;font-size:.92em}th,td{border:1px solid #ccc;padding:.25em .6em;text-align:left;vertical-align:top}
th{background:#f3f3f3}td.num{text-align:right;font-variant-numeric:tabular-nums}
img{max-width:100%;border:1px solid #eee;margin:.4em 0}figure{margin:.6em 0 1.4em}figcaption{font-size:.88em;color:#555}
.missing{color:#a66;font-style:italic}.warning{color:#a50}.error{color:#b00;font-family:monospace;white-space:pre-wrap}
.departures{background:#fff6e5;border-left:4px solid #e0a030;padding:.4em 1em}td.differs{color:#b00;font-weight:600}
nav a{margin-right:1em}details{margin:.6em 0}summary{cursor:pointer;color:#444}p.explore{background:#eef5ee;padding:.5em .8em;border-left:3px solid #5a5}code,pre{background:#f6f6f6;padding:.1em .3em}pre{padding:.6em;overflow-x:auto;font-size:.85em}
"""


def esc(value: Any) -> str:
    return html.escape(str(value))


def fmt(value: Any, digits: int = 4) -> str:
    """A number as text (``n/a`` for None or NaN); other values as given."""
    if value is None:
        return "n/a"
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value))
    if isinstance(value, (int, np.integer)):
        return f"{int(value):,}"
    if isinstance(value, (float, np.floating)):
        return "n/a" if not np.isfinite(value) else f"{float(value):.{digits}g}"
    return str(value)


def number(key: str, value: float | None, digits: int = 4, suffix: str = "") -> str:
    """A table cell holding a number, machine-readable through ``data-key`` / ``data-value``."""
    data = "nan" if value is None or not np.isfinite(value) else repr(float(value))
    return f'<td class="num" data-key="{esc(key)}" data-value="{data}">{fmt(value, digits)}{esc(suffix)}</td>'


def table(head: list[str], rows: list[list[str]], raw_cells: bool = False) -> str:
    """An HTML table; cells are escaped unless ``raw_cells`` (they are pre-rendered ``<td>`` s)."""
    header = "".join(f"<th>{esc(h)}</th>" for h in head)
    body = "".join("<tr>" + ("".join(row) if raw_cells else "".join(f"<td>{esc(c)}</td>" for c in row)) + "</tr>" for row in rows)
    return f"<table><thead><tr>{header}</tr></thead><tbody>{body}</tbody></table>"


def image(path: Path, caption: str) -> str:
    """A PNG embedded as base64 (the report stays one file), or a note that it is missing."""
    if not path.is_file():
        return missing(f"figure not drawn ({path.name})")
    data = base64.b64encode(path.read_bytes()).decode()
    return f'<figure><img alt="{esc(caption)}" src="data:image/png;base64,{data}"><figcaption>{esc(caption)}</figcaption></figure>'


def missing(text: str) -> str:
    return f'<p class="missing">{esc(text)}</p>'


def phase_state(entry: dict | None) -> str | None:
    """None when the phase is done; otherwise a paragraph saying it is not run, running or failed."""
    if not entry:
        return missing("not run")
    status = entry.get("status")
    if status == "done":
        return None
    if status == "failed":
        return f'<p class="missing">failed:</p><p class="error">{esc(entry.get("error", ""))}</p>'
    return missing(f"not finished ({status}); run reproduce again on this run directory to resume it")


def section(anchor: str, title: str, body: str) -> str:
    return f'<section id="{anchor}"><h2>{esc(title)}</h2>\n{body}\n</section>'
