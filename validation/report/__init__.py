"""Reports: pyvista figures (:mod:`.figures`) and a static offline HTML page (:mod:`.html`).

The figure functions take plain arrays and write PNGs; :func:`.html.write_html`
assembles :class:`.html.Section` objects (text, tables, figures) into one page.
The validation report (:mod:`.validation_report`) and the gap diagnosis build
on both.
"""
from .html import Figure, Section, Table, format_number, write_html

__all__ = ["Figure", "Section", "Table", "format_number", "write_html"]
