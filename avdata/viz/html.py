"""Reports as one self-contained web page: tables, inline PNG pictures, sortable columns, no other host.

``avdata stats`` and ``avdata study report`` write ``report.html`` with :func:`write_html_report`. Everything
the page shows is inside the file: pictures are ``data:image/png;base64`` URLs, the sorting script and the
style are inline, and a Content-Security-Policy forbids loading anything else, so the page looks the same
offline, in a mail attachment or on a cluster's file share. A click on a column header sorts the table by
that column (numbers as numbers); each cell keeps the exact value of the CSV/Markdown output it comes from.
"""

from __future__ import annotations

import base64
import html
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from avdata.outputs import write_atomically

__all__ = ["Cell", "Picture", "Section", "Table", "html_report", "png_picture", "write_html_report"]

#: Nothing but the page itself: inline style and script, pictures as data: URLs.
_CSP = "default-src 'none'; img-src data:; style-src 'unsafe-inline'; script-src 'unsafe-inline'"

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1200px; padding: 0 1em; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: right; white-space: nowrap; }
th:first-child, td:first-child { text-align: left; }
th { background: #f0f0f0; cursor: pointer; user-select: none; }
th[aria-sort="ascending"]::after { content: " \\25B2"; }
th[aria-sort="descending"]::after { content: " \\25BC"; }
figure { display: inline-block; margin: 0.5em 1em 1em 0; vertical-align: top; }
figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.85em; color: #555; }
nav a { margin-right: 1em; }
.note { color: #a33; }
.scroll { overflow-x: auto; }
"""

# Sorts a table by the clicked column: cells with a data-sort number compare as numbers, the rest as text.
_SCRIPT = """
document.querySelectorAll("table.sortable th").forEach(function (th, column) {
  th.addEventListener("click", function () {
    var table = th.closest("table"), body = table.tBodies[0];
    var ascending = th.getAttribute("aria-sort") !== "ascending";
    table.querySelectorAll("th").forEach(function (h) { h.removeAttribute("aria-sort"); });
    th.setAttribute("aria-sort", ascending ? "ascending" : "descending");
    var key = function (row) {
      var cell = row.cells[th.cellIndex], n = cell.getAttribute("data-sort");
      return n === null ? cell.textContent : parseFloat(n);
    };
    var rows = Array.prototype.slice.call(body.rows);
    rows.sort(function (a, b) {
      var x = key(a), y = key(b), order;
      if (typeof x === "number" && typeof y === "number") { order = (isNaN(x) - isNaN(y)) || x - y || 0; }
      else { order = String(x).localeCompare(String(y)); }
      return ascending ? order : -order;
    });
    rows.forEach(function (row) { body.appendChild(row); });
  });
});
"""


#: A table cell: its text, or its text and the exact number behind it.
Cell = str | tuple[str, float]


@dataclass(frozen=True, slots=True)
class Table:
    """A table of the page; each cell is shown as its text, and sorted by its number when it has one.

    Attributes:
        title: caption above the table.
        columns: header cells.
        rows: cells per row: text, or (text, number) where the text rounds the number; the number is kept
            exactly in the cell's ``data-sort`` attribute, which sorting uses (a text cell sorts by its first
            number, else as text).
    """

    title: str
    columns: Sequence[str]
    rows: Sequence[Sequence[Cell]]


@dataclass(frozen=True, slots=True)
class Picture:
    """A PNG shown inline.

    Attributes:
        caption: text under the picture.
        png: the PNG file's bytes.
    """

    caption: str
    png: bytes


@dataclass(frozen=True, slots=True)
class Section:
    """A part of the page with its own heading and entry in the page's navigation.

    Attributes:
        title: heading.
        text: paragraphs before the tables.
        tables: tables, in order.
        pictures: pictures after the tables.
        notes: lines saying what could not be shown and why.
    """

    title: str
    text: Sequence[str] = ()
    tables: Sequence[Table] = ()
    pictures: Sequence[Picture] = ()
    notes: Sequence[str] = field(default_factory=tuple)


def png_picture(caption: str, path: str | Path) -> Picture:
    """A :class:`Picture` of the PNG file at ``path``."""
    return Picture(caption, Path(path).read_bytes())


def _sort_key(cell: Cell) -> tuple[str, str | None]:
    """A cell's text and the number it sorts by: its own, else the text's first ("0.35 +/- 0.02": 0.35), else None."""
    if isinstance(cell, tuple):
        text, value = cell
    else:
        text = cell
        try:
            value = float(text.strip().split(" ")[0]) if text.strip() else math.nan
        except ValueError:
            return text, None
        if not text.strip():
            return text, None
    return text, repr(float(value)) if math.isfinite(value) else "NaN"


def _table(table: Table) -> str:
    head = "".join(f"<th>{html.escape(c)}</th>" for c in table.columns)
    rows = []
    for row in table.rows:
        cells = []
        for cell in row:
            text, key = _sort_key(cell)
            attribute = "" if key is None else f' data-sort="{key}"'
            cells.append(f"<td{attribute}>{html.escape(text)}</td>")
        rows.append("<tr>" + "".join(cells) + "</tr>")
    return (f"<h3>{html.escape(table.title)}</h3>\n<div class=\"scroll\"><table class=\"sortable\">"
            f"<thead><tr>{head}</tr></thead>\n<tbody>\n" + "\n".join(rows) + "\n</tbody></table></div>")


def _picture(picture: Picture) -> str:
    data = base64.b64encode(picture.png).decode("ascii")
    caption = html.escape(picture.caption)
    return f'<figure><img src="data:image/png;base64,{data}" alt="{caption}"><figcaption>{caption}</figcaption></figure>'


def html_report(title: str, sections: Sequence[Section]) -> str:
    """The page's HTML text."""
    anchors = [f"section-{i}" for i in range(len(sections))]
    nav = " ".join(f'<a href="#{a}">{html.escape(s.title)}</a>' for a, s in zip(anchors, sections, strict=True))
    parts = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
             f'<meta http-equiv="Content-Security-Policy" content="{_CSP}">',
             '<meta name="viewport" content="width=device-width, initial-scale=1">',
             f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head><body>",
             f"<h1>{html.escape(title)}</h1>", f"<nav>{nav}</nav>"]
    for anchor, section in zip(anchors, sections, strict=True):
        parts.append(f'<section id="{anchor}"><h2>{html.escape(section.title)}</h2>')
        parts += [f"<p>{html.escape(paragraph)}</p>" for paragraph in section.text if paragraph]
        parts += [_table(t) for t in section.tables]
        parts += [f'<p class="note">{html.escape(note)}</p>' for note in section.notes]
        parts += [_picture(p) for p in section.pictures]
        parts.append("</section>")
    parts += [f"<script>{_SCRIPT}</script>", "</body></html>"]
    return "\n".join(parts) + "\n"


def write_html_report(path: str | Path, title: str, sections: Sequence[Section]) -> Path:
    """Writes :func:`html_report` to ``path`` (whole or not at all); returns the path."""
    path = Path(path)
    write_atomically(path, html_report(title, sections))
    return path
