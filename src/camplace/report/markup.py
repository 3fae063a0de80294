"""Small HTML helpers of the report: escaping, numbers, tables, embedded images (no report logic)."""

from __future__ import annotations

import base64
import html
import math
from typing import Any, Sequence

import numpy as np

__all__ = ["esc", "_num", "_vec", "_table", "_img"]


def esc(value: Any) -> str:
    """HTML-escaped ``str(value)``."""
    return html.escape(str(value), quote=True)


def _num(v: Any, digits: int = 4) -> str:
    if v is None:
        return "–"
    if isinstance(v, (int, np.integer)) and not isinstance(v, bool):
        return f"{int(v):,}"
    try:
        f = float(v)
    except (TypeError, ValueError):
        return esc(v)
    if not math.isfinite(f):
        return "–"
    return f"{f:.{digits}f}"


def _vec(v: Sequence[float], digits: int = 3) -> str:
    return "(" + ", ".join(f"{float(x):.{digits}f}" for x in v) + ")"


def _table(header: Sequence[str] | None, rows: Sequence[Sequence[Any]], left: int = 1) -> str:
    """An HTML table; cells are escaped unless given as ``("raw", html)``; the first ``left`` columns are left-aligned."""
    def cell(tag: str, i: int, v: Any) -> str:
        cls = ' class="l"' if i < left else ""
        text = v[1] if isinstance(v, tuple) and len(v) == 2 and v[0] == "raw" else esc(v)
        return f"<{tag}{cls}>{text}</{tag}>"

    out = ["<table>"]
    if header:
        out.append("<thead><tr>" + "".join(cell("th", i, h) for i, h in enumerate(header)) + "</tr></thead>")
    out.append("<tbody>")
    for r in rows:
        out.append("<tr>" + "".join(cell("td", i, v) for i, v in enumerate(r)) + "</tr>")
    out.append("</tbody></table>")
    return "".join(out)


def _img(png: bytes, alt: str, caption: str = "", width: int | None = None) -> str:
    b64 = base64.b64encode(png).decode("ascii")
    w = f' width="{int(width)}"' if width else ""
    cap = f"<figcaption>{caption}</figcaption>" if caption else ""
    return f'<figure><img src="data:image/png;base64,{b64}" alt="{esc(alt)}"{w}>{cap}</figure>'
