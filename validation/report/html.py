"""A static, offline HTML report: sections of text, tables and figures.

The page has its style inline and refers to its figures by paths relative to
the page (``embed=True`` puts the PNGs into the page itself), so the folder
can be zipped, mailed and opened anywhere without a server or network.

Example
-------
>>> import tempfile, pathlib
>>> out = pathlib.Path(tempfile.mkdtemp())
>>> page = write_html(out / "index.html", "Validation", [
...     Section("Errors", "Mean relative error of the currents.",
...             tables=[Table(["model", "mean (%)"], [["BEM", 2.06]], caption="bench vs models")])])
>>> "<table" in page.read_text()
True
"""
from __future__ import annotations

import base64
import html
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

__all__ = ["Table", "Figure", "Section", "write_html", "format_number"]

_STYLE = """
body { font-family: Helvetica, Arial, sans-serif; max-width: 72em; margin: 1.5em auto; padding: 0 1em;
       color: #222; line-height: 1.45; }
.table-wrap { max-width: 100%; overflow-x: auto; }
h1 { border-bottom: 2px solid #305080; padding-bottom: .2em; }
h2 { color: #305080; margin-top: 2em; border-bottom: 1px solid #ccd; }
h3 { color: #444; }
table { border-collapse: collapse; margin: 1em 0; font-size: 0.95em; }
caption { caption-side: top; text-align: left; font-weight: bold; padding-bottom: .4em; }
th, td { border: 1px solid #bbc; padding: .3em .7em; text-align: right; }
th { background: #eef1f7; }
td:first-child, th:first-child { text-align: left; }
tr:nth-child(even) td { background: #f8f9fb; }
figure { margin: 1.5em 0; }
figure img { max-width: 100%; height: auto; border: 1px solid #ddd; }
figure a.vector { font-size: 0.85em; }
figcaption { font-size: 0.95em; color: #444; margin-top: .3em; }
.side-by-side { display: flex; gap: 1em; flex-wrap: wrap; align-items: flex-start; }
.side-by-side figure { flex: 1 1 24em; min-width: 0; }
@media (max-width: 40em) { body { padding: 0 .4em; } th, td { padding: .2em .4em; } }
.note { background: #fff8e0; border-left: 4px solid #e0b000; padding: .5em 1em; }
pre { background: #f4f4f4; padding: .6em; overflow-x: auto; }
footer { margin-top: 3em; font-size: 0.85em; color: #777; }
"""


def format_number(value, digits: int = 4) -> str:
    """A table cell: floats to ``digits`` significant digits, None as an em dash, the rest as text."""
    if value is None:
        return "\u2014"
    if isinstance(value, bool):
        return str(value)
    if isinstance(value, float):
        if value != value:  # NaN is shown, never hidden
            return "NaN"
        return f"{value:.{digits}g}"
    return str(value)


@dataclass
class Table:
    """A table: a header row and rows of cells (numbers are formatted by :func:`format_number`)."""

    header: Sequence[str]
    rows: Sequence[Sequence]
    caption: str = ""
    digits: int = 4

    def __post_init__(self):
        for i, row in enumerate(self.rows):
            if len(row) != len(self.header):
                raise ValueError(
                    f"table {self.caption!r}: row {i} has {len(row)} cells for {len(self.header)} columns"
                )

    def to_html(self) -> str:
        head = "".join(f"<th>{html.escape(str(h))}</th>" for h in self.header)
        body = "\n".join(
            "<tr>" + "".join(f"<td>{html.escape(format_number(c, self.digits))}</td>" for c in row) + "</tr>"
            for row in self.rows
        )
        cap = f"<caption>{html.escape(self.caption)}</caption>" if self.caption else ""
        return (f'<div class="table-wrap"><table>{cap}<thead><tr>{head}</tr></thead><tbody>\n{body}\n'
                "</tbody></table></div>")


@dataclass
class Figure:
    """A PNG (path) with its caption."""

    path: str | os.PathLike
    caption: str = ""

    def to_html(self, page_folder: Path, embed: bool = False) -> str:
        path = Path(self.path)
        if not path.exists():
            raise ValueError(f"figure {path} does not exist")
        if embed:
            src = "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode()
        else:
            src = Path(os.path.relpath(path.resolve(), page_folder.resolve())).as_posix()
        vector = [v for v in (path.with_suffix(".pdf"), path.with_suffix(".svg")) if v.exists()]
        link = ""
        if vector and not embed:  # the vector copy for a paper, beside the PNG
            href = Path(os.path.relpath(vector[0].resolve(), page_folder.resolve())).as_posix()
            link = f' <a class="vector" href="{html.escape(href)}">({vector[0].suffix[1:].upper()})</a>'
        cap = f"<figcaption>{html.escape(self.caption)}{link}</figcaption>" if self.caption or link else ""
        alt = html.escape(self.caption or path.stem)
        return f'<figure><img src="{html.escape(src)}" alt="{alt}">{cap}</figure>'


@dataclass
class Section:
    """A titled part of the page: paragraphs, tables, figures (optionally side by side), subsections.

    ``text`` is plain text (escaped); a list gives several paragraphs.
    ``notes`` are highlighted paragraphs (warnings, skipped figures).
    """

    title: str
    text: str | Sequence[str] = ""
    tables: Sequence[Table] = field(default_factory=list)
    figures: Sequence[Figure] = field(default_factory=list)
    side_by_side: bool = False
    notes: Sequence[str] = field(default_factory=list)
    subsections: Sequence["Section"] = field(default_factory=list)
    preformatted: str = ""
    links: Sequence[tuple[str, str]] = field(default_factory=list)
    """(text, relative href) pairs, e.g. another report beside this one."""

    def to_html(self, page_folder: Path, level: int = 2, embed: bool = False) -> str:
        parts = [f"<h{level}>{html.escape(self.title)}</h{level}>"]
        paragraphs = [self.text] if isinstance(self.text, str) else list(self.text)
        parts += [f"<p>{html.escape(p)}</p>" for p in paragraphs if p]
        parts += [f'<p class="note">{html.escape(n)}</p>' for n in self.notes]
        if self.links:
            parts.append("<ul>" + "".join(f'<li><a href="{html.escape(href)}">{html.escape(text)}</a></li>'
                                          for text, href in self.links) + "</ul>")
        if self.preformatted:
            parts.append(f"<pre>{html.escape(self.preformatted)}</pre>")
        parts += [t.to_html() for t in self.tables]
        figures = [f.to_html(page_folder, embed) for f in self.figures]
        if figures:
            parts.append('<div class="side-by-side">' + "".join(figures) + "</div>" if self.side_by_side else "".join(figures))
        parts += [s.to_html(page_folder, min(level + 1, 6), embed) for s in self.subsections]
        return "\n".join(parts)


def write_html(path, title: str, sections: Sequence[Section], intro: str | Sequence[str] = "",
               footer: str = "", embed: bool = False) -> Path:
    """Write a self-contained static page and return its path.

    Parameters
    ----------
    path : path-like
        The page (``index.html``); its folder is created.
    title : str
    sections : sequence of Section
    intro : str or list of str
        Paragraphs under the title.
    footer : str
        Small print (provenance: versions, command line).
    embed : bool
        Put the figures into the page (base64) instead of linking the PNG files.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    folder = path.parent
    paragraphs = [intro] if isinstance(intro, str) else list(intro)
    contents = "".join(
        f'<li><a href="#s{i}">{html.escape(s.title)}</a></li>' for i, s in enumerate(sections)
    )
    body = "\n".join(
        f'<section id="s{i}">{s.to_html(folder, 2, embed)}</section>' for i, s in enumerate(sections)
    )
    page = (
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
        f"<title>{html.escape(title)}</title>\n<style>{_STYLE}</style>\n</head>\n<body>\n"
        f"<h1>{html.escape(title)}</h1>\n"
        + "".join(f"<p>{html.escape(p)}</p>" for p in paragraphs if p)
        + (f"<nav><ul>{contents}</ul></nav>\n" if len(sections) > 1 else "")
        + body
        + (f"\n<footer>{html.escape(footer)}</footer>" if footer else "")
        + "\n</body>\n</html>\n"
    )
    path.write_text(page, encoding="utf-8")
    return path
