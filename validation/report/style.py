"""One look for every 2D figure of the reports (matplotlib, Agg canvas): sizes, fonts, colours, saving.

Figures are made with :func:`new_figure` (a ``matplotlib.figure.Figure`` on an
Agg canvas, never pyplot, so that no window and no global backend are
involved) and written with :func:`save`: a PNG for the page and a vector PDF
beside it for a paper. Relative errors are labelled with one convention
everywhere, :data:`RELATIVE_ERROR_LABEL`: simulation / bench - 1 (positive:
the simulation predicts more current than the bench measured).

Example
-------
>>> import tempfile, pathlib
>>> fig, axes = new_figure(1, 1)
>>> _ = axes[0, 0].plot([0, 1], [0, 1])
>>> png = save(fig, pathlib.Path(tempfile.mkdtemp()) / "line.png")
>>> png.exists(), png.with_suffix(".pdf").exists()
(True, True)
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

__all__ = ["RC", "DPI", "PANEL_SIZE_IN", "COLOURS", "CYCLE", "RELATIVE_ERROR_LABEL", "VECTOR_FORMAT", "new_figure",
           "save", "colour_of", "symmetric_limit"]

#: matplotlib settings of every report figure (sizes in points for a page about 17 cm wide)
RC = {
    "font.size": 9.0,
    "axes.titlesize": 9.5,
    "axes.labelsize": 9.0,
    "xtick.labelsize": 8.0,
    "ytick.labelsize": 8.0,
    "legend.fontsize": 8.0,
    "legend.frameon": False,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "axes.grid": True,
    "grid.color": "#e4e4e4",
    "grid.linewidth": 0.6,
    "axes.axisbelow": True,
    "lines.linewidth": 1.4,
    "lines.markersize": 3.5,
    "pdf.fonttype": 42,  # TrueType in the PDF: text stays text for journals
    "svg.fonttype": "none",
    "savefig.dpi": 200,
}
DPI = RC["savefig.dpi"]
#: width, height of one panel (inches)
PANEL_SIZE_IN = (3.6, 2.6)
#: the vector copy written beside every PNG
VECTOR_FORMAT = "pdf"

#: colours of the usual series, the same in every figure
COLOURS = {
    "bench": "black",
    "bench (corrected)": "#8c8c8c",
    "bem": "#1f5fbf",
    "psm": "#d9541a",
    "bem-psm": "#6a3d9a",
    "psm vs bem": "#6a3d9a",
    "noise": "#7f7f7f",
}
CYCLE = ("#1f5fbf", "#d9541a", "#2ca02c", "#6a3d9a", "#b8860b", "#17becf", "#e377c2", "#7f7f7f")

#: the one sign convention of relative errors in the reports
RELATIVE_ERROR_LABEL = "simulation / bench - 1 (%)"


def colour_of(name: str, k: int = 0) -> str:
    """The usual colour of a series named ``name`` (or of its first word), else the k-th of :data:`CYCLE`."""
    key = str(name).lower()
    if key in COLOURS:
        return COLOURS[key]
    words = key.replace("/", " ").split()
    return COLOURS.get(words[0] if words else key, CYCLE[k % len(CYCLE)])


def new_figure(nrows: int = 1, ncols: int = 1, panel_size_in: Sequence[float] = PANEL_SIZE_IN, **subplot_kw):
    """A figure of ``nrows`` x ``ncols`` panels on an Agg canvas, constrained layout; returns (figure, 2D axes)."""
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    with matplotlib.rc_context(RC):
        fig = Figure(figsize=(panel_size_in[0] * ncols, panel_size_in[1] * nrows), layout="constrained")
        FigureCanvasAgg(fig)
        axes = fig.subplots(nrows, ncols, squeeze=False, **subplot_kw)
    fig._esense_rc = RC  # save() draws under the same settings
    return fig, axes


def save(fig, png_path, vector: str | None = VECTOR_FORMAT) -> Path:
    """Write ``fig`` as a PNG and (``vector``: ``"pdf"`` or ``"svg"``) a vector copy beside it; return the PNG."""
    import matplotlib

    png_path = Path(png_path)
    png_path.parent.mkdir(parents=True, exist_ok=True)
    with matplotlib.rc_context(getattr(fig, "_esense_rc", RC)):
        fig.savefig(png_path, dpi=DPI, facecolor="white")
        if vector:
            # the layout is in inches, the same for both: computed once (a panel grid's layout is half a save)
            engine = fig.get_layout_engine()
            fig.set_layout_engine("none")
            try:
                fig.savefig(png_path.with_suffix("." + vector), facecolor="white")
            finally:
                fig.set_layout_engine(engine)
    return png_path


def symmetric_limit(values, floor: float = 0.0, percentile: float = 99.0) -> float:
    """Half range of a colour scale centred on 0: the ``percentile`` of |values|, never below ``floor``.

    The floor (the noise level, say) keeps a map of pure noise from being
    stretched over the whole colour scale.

    >>> symmetric_limit([-1e-9, 2e-9], floor=0.01)
    0.01
    >>> symmetric_limit([-3.0, 1.0, 2.0], percentile=100)
    3.0
    """
    v = np.abs(np.asarray(values, dtype=float))
    v = v[np.isfinite(v)]
    top = float(np.percentile(v, percentile)) if v.size else 0.0
    return max(top, float(floor)) or 1.0
