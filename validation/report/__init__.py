"""Reports: figures (:mod:`.figures`; 2D with matplotlib in the style of :mod:`.style`, PNG with a PDF beside
it; 3D scenes with pyvista) and a static offline HTML page (:mod:`.html`).

Reusable pieces (plain arrays in, PNG or HTML out):

* :func:`.figures.curves_figure` with :class:`.figures.Panel` / :class:`.figures.Series`: a grid of
  2D plots (lines, markers, dashed styles, one legend above the panels, axis labels with units);
* :func:`.figures.bar_figure`: grouped bars over named categories (e.g. regions of a path);
* :func:`.figures.scene_figure`: tank, sensor mesh with its electrodes coloured, a path coloured by a value
  (needs an offscreen OpenGL, see :func:`electrosense.meshes.render.can_render_3d`);
* :func:`.figures.potential_figure`: a potential map with equipotentials and current lines;
* :func:`.figures.png_is_blank`: for tests;
* :func:`.html.write_html` with :class:`.html.Section`, :class:`.html.Table`, :class:`.html.Figure`.

The validation report (:mod:`.validation_report`) assembles them for ``esense validate`` and
``esense demo``; the gap diagnosis can use the same pieces.
"""
from electrosense.validation.report.html import Figure, Section, Table, format_number, write_html

__all__ = ["Figure", "Section", "Table", "format_number", "write_html"]
