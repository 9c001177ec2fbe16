"""Figures of the validation and diagnosis reports.

Two kinds of figures:

* 2D plots, drawn with matplotlib (:mod:`.style` gives their common look and
  writes a PNG with a vector PDF beside it): curves (:func:`curves_figure`, a
  grid of :class:`Panel` s, each a list of :class:`Series`), grouped bars
  (:func:`bar_figure`), the report-specific :func:`resistance_figure` and
  :func:`relative_error_figure`, and the potential map
  (:func:`potential_figure`); the gap diagnosis reuses the same pieces.
* 3D scenes (:func:`scene_figure`), drawn with pyvista offscreen: the tank,
  the sensor mesh with its electrodes coloured and the emitter named, the path
  coloured by a value. They need an offscreen OpenGL
  (:func:`electrosense.meshes.render.can_render_3d`); without one they raise
  :class:`electrosense.meshes.render.RenderUnavailable` and the reports leave them out.

Every function takes plain arrays (and meshes), writes one PNG and returns its
path. Relative errors follow one sign convention,
:data:`.style.RELATIVE_ERROR_LABEL` (simulation / bench - 1).

Example
-------
>>> import numpy as np, tempfile, os
>>> x = np.linspace(-0.4, 0.4, 20)
>>> panel = Panel("receiver 1", "x (m)", "U/I (ohm)", [Series(x, 600 + 500 * x**2, "bench")])
>>> path = curves_figure([panel], os.path.join(tempfile.mkdtemp(), "r.png"))
>>> path.exists(), path.with_suffix(".pdf").exists()
(True, True)
"""
from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from electrosense.meshes.cylinder_tank import CylinderTank
from electrosense.validation.report.style import (
    COLOURS,
    CYCLE,
    DPI,
    PANEL_SIZE_IN,
    RELATIVE_ERROR_LABEL,
    VECTOR_FORMAT,
    colour_of,
    new_figure,
    save,
)

__all__ = [
    "Series",
    "Panel",
    "curves_figure",
    "bar_figure",
    "resistance_figure",
    "relative_error_figure",
    "scene_figure",
    "potential_figure",
    "current_lines",
    "path_coordinate",
    "png_is_blank",
    "COLOURS",
]

#: legend places a panel accepts: matplotlib's, "outside" (one legend above all panels, off the data) and none
_LEGEND_LOCS = ("outside", "none", "best", "upper right", "upper left", "lower left", "lower right", "right",
                "center left", "center right", "lower center", "upper center", "center")


@dataclass
class Series:
    """One curve of a panel.

    ``kind`` is ``"line"`` or ``"scatter"``; ``label`` ``""`` keeps it out of
    the legend (e.g. the second pass of the same model).
    """

    x: np.ndarray
    y: np.ndarray
    label: str = ""
    kind: str = "line"
    colour: str | None = None
    width: float = 1.4
    marker_size: float = 3.5
    marker: str = "o"
    style: str = "-"

    def __post_init__(self):
        self.x = np.asarray(self.x, dtype=float).ravel()
        self.y = np.asarray(self.y, dtype=float).ravel()
        if self.x.shape != self.y.shape:
            raise ValueError(f"series {self.label!r}: x has {self.x.size} values but y has {self.y.size}")
        if self.kind not in ("line", "scatter"):
            raise ValueError(f"series {self.label!r}: kind must be 'line' or 'scatter', got {self.kind!r}")


@dataclass
class Panel:
    """One chart: a title, axis labels with units, and its series.

    ``legend_loc``: ``"outside"`` (default) gathers the legends of all panels
    into one above the figure, off the data; a matplotlib place (``"upper
    right"``...) puts it inside this panel; ``"none"`` draws none.
    ``y_log``: logarithmic y axis. ``zero_line``: a thin line at y = 0.
    """

    title: str
    x_label: str
    y_label: str
    series: list[Series] = field(default_factory=list)
    y_range: tuple[float, float] | None = None
    x_range: tuple[float, float] | None = None
    legend_loc: str = "outside"
    y_log: bool = False
    zero_line: bool = False
    band: tuple[float, float, str] | None = None
    """(low, high, label): a shaded band across the panel, e.g. the noise level."""

    def __post_init__(self):
        loc = self.legend_loc.replace("centre", "center")
        if loc not in _LEGEND_LOCS:
            raise ValueError(f"panel {self.title!r}: legend_loc {self.legend_loc!r} is not one of "
                             f"{', '.join(_LEGEND_LOCS)}")
        self.legend_loc = loc


def _px_to_in(size) -> tuple[float, float]:
    """A panel size in pixels of the PNG (at :data:`.style.DPI`) as inches; inches pass through."""
    w, h = size
    return (w / DPI, h / DPI) if max(w, h) > 40 else (float(w), float(h))


def _draw_panel(ax, panel: Panel):
    if panel.band is not None:
        lo, hi, label = panel.band
        ax.axhspan(lo, hi, color="#d8d8d8", alpha=0.6, lw=0, label=label, zorder=0)
    if panel.zero_line:
        ax.axhline(0.0, color="#444444", lw=0.7, zorder=1)
    for s in panel.series:
        colour = s.colour or "black"
        if s.kind == "line":
            ax.plot(s.x, s.y, s.style, color=colour, lw=s.width, label=s.label or None, zorder=2)
        else:
            ax.plot(s.x, s.y, linestyle="none", marker=s.marker, ms=s.marker_size, color=colour,
                    mec="none" if s.marker != "d" else colour, label=s.label or None, zorder=3)
    if panel.y_log:
        ax.set_yscale("log")
    ax.margins(x=0.03, y=0.06)  # whole markers at the ends, never half clipped by the frame
    if panel.y_range is not None:
        ax.set_ylim(*panel.y_range)
    if panel.x_range is not None and panel.x_range[1] > panel.x_range[0]:
        ax.set_xlim(*panel.x_range)
    ax.set_title(panel.title)
    ax.set_xlabel(panel.x_label)
    ax.set_ylabel(panel.y_label)
    if panel.legend_loc not in ("outside", "none") and ax.get_legend_handles_labels()[1]:
        ax.legend(loc=panel.legend_loc)


def _shared_legend(fig, axes_panels):
    """One legend above the panels for every panel whose legend is 'outside' (each label once)."""
    entries = {}
    for ax, panel in axes_panels:
        if panel.legend_loc != "outside":
            continue
        for handle, label in zip(*ax.get_legend_handles_labels()):
            entries.setdefault(label, handle)
    if entries:
        # entries per row that fit the figure's width (8 pt text: about 0.062 inch a character)
        entry_in = 0.75 + 0.062 * max(len(label) for label in entries)
        per_row = max(1, min(len(entries), 4, int(fig.get_figwidth() // entry_in)))
        if math.ceil(len(entries) / per_row) > 2:  # a narrow figure: the legend beside it, not over its height
            fig.set_figwidth(fig.get_figwidth() + entry_in)
            fig.legend(list(entries.values()), list(entries), loc="outside right upper", handlelength=2.2,
                       markerscale=1.5)
            return
        fig.legend(list(entries.values()), list(entries), loc="outside upper center", ncols=per_row,
                   handlelength=2.2, markerscale=1.5)


def curves_figure(panels: Sequence[Panel], png_path, ncols: int | None = None, panel_size=PANEL_SIZE_IN,
                  title: str = "", share_y: bool = False, vector: str | None = VECTOR_FORMAT) -> Path:
    """Draw panels of 2D curves on a grid (``ncols`` per row) and save a PNG (and a PDF beside it).

    Parameters
    ----------
    panels : sequence of Panel
    png_path : path-like
    ncols : int, optional
        Panels per row (default: all in one row up to 3).
    panel_size : (float, float)
        Inches per panel (or pixels of the PNG, when larger than 40).
    title : str
        Heading above the whole figure.
    share_y : bool
        One y range for all panels.
    vector : str or None
        The vector copy beside the PNG (:func:`~electrosense.validation.report.style.save`; None: none).
    """
    panels = list(panels)
    if not panels:
        raise ValueError("curves_figure needs at least one panel")
    ncols = ncols or min(len(panels), 3)
    nrows = math.ceil(len(panels) / ncols)
    fig, axes = new_figure(nrows, ncols, _px_to_in(panel_size), sharey=share_y)
    for i, panel in enumerate(panels):
        _draw_panel(axes.flat[i], panel)
        if share_y and i % ncols:      # one y axis a row: its label and ticks on the first panel only
            axes.flat[i].set_ylabel("")
    for ax in axes.flat[len(panels):]:
        ax.set_visible(False)
    _shared_legend(fig, list(zip(axes.flat, panels)))
    if title:
        fig.suptitle(title)
    return save(fig, png_path, vector)


def bar_figure(categories: Sequence[str], values: dict, png_path, title: str, y_label: str, panel_size=None,
               y_max: float | None = None, counts: Sequence[int] | None = None, log: bool | None = None,
               horizontal: bool | None = None, lines: dict | None = None, vector: str | None = VECTOR_FORMAT) -> Path:
    """Grouped bars: one group per category, one bar colour per key of ``values``.

    Parameters
    ----------
    categories : sequence of str
        Names of the groups (e.g. regions of the path, candidate effects).
    values : dict
        Label -> (len(categories),) array (e.g. model -> mean |error| in %).
    y_label : str
        The values' axis, with its unit.
    y_max : float, optional
        Cut bars above it and write their value at the cut (linear scale only).
    counts : sequence of int, optional
        Samples behind each category, written under its name ("n = 40").
    log : bool, optional
        Logarithmic value axis; default: when the positive values span more
        than a factor 30.
    horizontal : bool, optional
        Bars along x with the names on the left (readable, never clipped);
        default: with more than 5 categories.
    lines : dict, optional
        Label -> value: reference levels drawn across the bars (a noise level, say).
    vector : str or None
        The vector copy beside the PNG (None: none).
    """
    if not len(categories) or not values:
        raise ValueError("bar_figure needs categories and at least one series of values")
    names = [str(c) for c in categories]
    if counts is not None:
        if len(counts) != len(names):
            raise ValueError(f"bar_figure: {len(counts)} counts for {len(names)} categories")
        names = [f"{c}\n(n = {int(n)})" for c, n in zip(names, counts)]
    arrays, colours = {}, []
    for k, (label, v) in enumerate(values.items()):
        v = np.asarray(v, dtype=float).ravel()
        if v.size != len(names):
            raise ValueError(f"bar series {label!r} has {v.size} values for {len(names)} categories")
        arrays[str(label)] = v
        colour = colour_of(str(label), k)
        spare = (c for c in CYCLE if c not in colours)
        colours.append(colour if colour not in colours else next(spare, colour))  # every bar series distinct
    every = np.concatenate(list(arrays.values()) + [np.asarray(list((lines or {}).values()), dtype=float)])
    positive = every[np.isfinite(every) & (every > 0)]
    if log is None:
        log = bool(positive.size and np.all(every[np.isfinite(every)] >= 0) and positive.max() > 30 * positive.min())
    if horizontal is None:
        horizontal = len(names) > 5
    n_series = len(arrays)
    width = 0.8 / n_series
    if panel_size is None:
        long = max(len(names) * (0.32 + 0.12 * n_series), 2.4)
        panel_size = (6.4, long) if horizontal else (max(len(names) * 0.9 * max(n_series, 1), 3.6), 3.0)
    fig, axes = new_figure(1, 1, _px_to_in(panel_size))
    ax = axes[0, 0]
    pos = np.arange(len(names), dtype=float)
    cut = y_max is not None and not log
    for i, ((label, v), colour) in enumerate(zip(arrays.items(), colours)):
        at = pos + (i - (n_series - 1) / 2) * width
        shown = np.minimum(v, y_max) if cut else v
        if log:
            shown = np.where(shown > 0, shown, np.nan)  # nothing to draw on a log axis
        if horizontal:
            ax.barh(at, shown, height=width, color=colour, label=label, zorder=2)
        else:
            ax.bar(at, shown, width=width, color=colour, label=label, zorder=2)
        for j in np.flatnonzero(cut & (v > (y_max if cut else np.inf))):
            text = f"{v[j]:.3g}"
            if horizontal:
                ax.annotate(text, (y_max, at[j]), xytext=(2, 0), textcoords="offset points", va="center", fontsize=7)
            else:
                ax.annotate(text, (at[j], y_max), xytext=(0, 2), textcoords="offset points", ha="center", fontsize=7)
    for k, (label, level) in enumerate((lines or {}).items()):
        if log and not float(level) > 0:
            continue  # a level of 0 has no place on a log axis
        style = dict(color=colour_of(label, n_series + k), ls="--", lw=1.0, label=label, zorder=3)
        (ax.axvline if horizontal else ax.axhline)(float(level), **style)
    if horizontal:
        ax.set_yticks(pos, names)
        ax.invert_yaxis()  # the first category on top, as in a table
        ax.set_xlabel(y_label)
        ax.grid(axis="y", visible=False)
        if log:
            ax.set_xscale("log")
        elif cut:
            ax.set_xlim(0, 1.12 * y_max)
    else:
        ax.set_xticks(pos, names)
        ax.set_ylabel(y_label)
        ax.grid(axis="x", visible=False)
        if log:
            ax.set_yscale("log")
        elif cut:
            ax.set_ylim(0, 1.12 * y_max)
    # a title wider than a narrow panel (few bars) is broken into lines, not cut at the figure's edge
    ax.set_title("\n".join(textwrap.wrap(title, max(24, int(8 * fig.get_size_inches()[0])))))
    _shared_legend(fig, [(ax, Panel(title, "", y_label))])
    return save(fig, png_path, vector)


# ---------------------------------------------------------------- path helpers
def path_coordinate(poses, passes=None) -> tuple[np.ndarray, str]:
    """The abscissa for plots along a path: x, y, or the arc length (m), with its label.

    x (or y) when the path runs mainly along it (its range is at least 5 times
    the others'), otherwise the distance travelled, counted from the start of
    each pass when ``passes`` (P,) labels them.
    """
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    if passes is not None and len(_segments(passes, len(poses))) > 1:
        x, label = path_coordinate(poses)
        if label.startswith("distance"):
            x = np.empty(len(poses))
            for idx in _segments(passes, len(poses)):
                x[idx] = path_coordinate(poses[idx])[0] if len(idx) > 1 else 0.0
            label = "distance along the pass (m)"
        return x, label
    span = np.ptp(poses[:, :3], axis=0) if len(poses) else np.zeros(3)
    for axis, name in ((0, "x"), (1, "y")):
        others = np.delete(span, axis)
        if span[axis] > 0 and span[axis] >= 5 * others.max():
            return poses[:, axis].copy(), f"sensor position {name} (m)"
    steps = np.linalg.norm(np.diff(poses[:, :3], axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)]), "distance along the path (m)"


def _segments(passes, n: int) -> list[np.ndarray]:
    """Index arrays of the passes (one segment when ``passes`` is None)."""
    if passes is None:
        return [np.arange(n)]
    passes = np.asarray(passes).ravel()
    return [np.flatnonzero(passes == p) for p in dict.fromkeys(passes.tolist())]



def _model_series(x, values, name, k, passes, kind="line") -> list[Series]:
    out = []
    for i, idx in enumerate(_segments(passes, len(x))):
        order = idx[np.argsort(x[idx], kind="stable")]
        out.append(Series(x[order], values[order], name if i == 0 else "", kind=kind, colour=colour_of(name, k)))
    return out


def _pass_rows(passes, n: int) -> list[tuple[str, np.ndarray]]:
    """(row title prefix, indices) per pass: one row of panels per pass, so that passes are never stacked."""
    segments = _segments(passes, n)
    if len(segments) == 1:
        return [("", segments[0])]
    labels = list(dict.fromkeys(np.asarray(passes).ravel().tolist()))
    return [(f"pass {p}, ", idx) for p, idx in zip(labels, segments)]


def _column_grid_figure(grid: list[list[Panel]], png_path) -> Path:
    """Rows of panels (one row a pass, one column a receiver) drawn with one y range down each column."""
    for j in range(len(grid[0]) if grid else 0):
        span = _common_range([s.y for row in grid for s in row[j].series])
        for row in grid:
            row[j].y_range = span
    return curves_figure([p for row in grid for p in row], png_path, ncols=len(grid[0]) if grid else 1)


def _common_range(values: list[np.ndarray], pad: float = 0.06):
    finite = np.concatenate([v[np.isfinite(v)] for v in values]) if values else np.array([])
    if not finite.size:
        return None
    lo, hi = float(finite.min()), float(finite.max())
    span = hi - lo or abs(hi) or 1.0
    return lo - pad * span, hi + pad * span


def resistance_figure(
    x_m,
    bench_ohm,
    models_ohm: dict,
    receivers: Sequence[int],
    png_path,
    corrected_bench_ohm=None,
    x_label: str = "sensor position x (m)",
    passes=None,
    title_prefix: str = "",
) -> Path:
    """Resistance U/I of each receiver against position: bench, models, corrected bench.

    The paper's figures 6 to 8 (x in m, resistance in ohm): one panel per
    receiver, and one row of panels per pass when there are several (same y
    range down a column).

    Parameters
    ----------
    x_m : (P,) array
        Abscissa of each pose (see :func:`path_coordinate`).
    bench_ohm : (P, m) array or None
        Measured U/I per receiver.
    models_ohm : dict
        Model name -> (P, m) array of simulated U/I.
    receivers : sequence of int
        The receivers' electrode numbers (panel titles).
    corrected_bench_ohm : (P, m) array, optional
        The bench after the conductivity correction.
    passes : (P,) array, optional
        Pass labels.
    """
    x = np.asarray(x_m, dtype=float).ravel()
    rows = _pass_rows(passes, len(x))
    grid = []
    for prefix, idx in rows:
        order = idx[np.argsort(x[idx], kind="stable")]
        row = []
        for j, k in enumerate(receivers):
            series = [Series(x[order], np.asarray(R, dtype=float)[order, j], name.upper(), "line",
                             colour_of(name, m)) for m, (name, R) in enumerate(models_ohm.items())]
            if corrected_bench_ohm is not None:
                series.append(Series(x[order], np.asarray(corrected_bench_ohm)[order, j], "bench (corrected)",
                                     "scatter", COLOURS["bench (corrected)"], marker="d", marker_size=3.5))
            if bench_ohm is not None:
                series.append(Series(x[order], np.asarray(bench_ohm)[order, j], "bench", "scatter", COLOURS["bench"]))
            row.append(Panel(f"{title_prefix}{prefix}receiver {k}", x_label, "resistance U/I (ohm)", series))
        grid.append(row)
    return _column_grid_figure(grid, png_path)


def lateral_signal_figure(
    x_m,
    bench_A,
    models_A: dict,
    names: Sequence[str],
    png_path,
    x_label: str = "sensor position x (m)",
    passes=None,
) -> Path:
    """The lateral signal (left minus right, :meth:`electrosense.meshes.sensor.SensorDescription.lateral_weights`) of
    each split electrode against position: bench (dots), models (lines), one panel per electrode (and pass).

    ``bench_A`` (P, s) or None and ``models_A`` (name -> (P, s)) in A; plotted in uA.
    """
    x = np.asarray(x_m, dtype=float).ravel()
    grid = []
    for prefix, idx in _pass_rows(passes, len(x)):
        order = idx[np.argsort(x[idx], kind="stable")]
        row = []
        for j, name in enumerate(names):
            series = [Series(x[order], 1e6 * np.asarray(I, dtype=float)[order, j], model.upper(), "line",
                             colour_of(model, m)) for m, (model, I) in enumerate(models_A.items())]
            if bench_A is not None:
                series.append(Series(x[order], 1e6 * np.asarray(bench_A)[order, j], "bench", "scatter",
                                     COLOURS["bench"]))
            row.append(Panel(f"{prefix}{name}", x_label, "left - right (uA)", series))
        grid.append(row)
    return _column_grid_figure(grid, png_path)


def relative_error_figure(
    x_m,
    errors: dict,
    receivers: Sequence[int],
    png_path,
    x_label: str = "sensor position x (m)",
    passes=None,
    title_prefix: str = "",
    percent: bool = True,
    y_label: str = RELATIVE_ERROR_LABEL,
    noise=None,
) -> Path:
    """Relative error against position, one panel per receiver (and per pass), one curve per comparison.

    Curves are coloured by model (the first word of the label); comparisons
    against the BEM ("... / BEM" or "... vs BEM") are dashed, those after a
    conductivity correction ("corrected" in the label) dash-dotted.

    Parameters
    ----------
    errors : dict
        Label (e.g. ``"BEM / bench - 1"``) -> (P, m) relative errors
        (fractions, simulation / reference - 1).
    percent : bool
        Plot in percent (default).
    y_label : str
        The axis (default :data:`.style.RELATIVE_ERROR_LABEL`).
    noise : float, optional
        Noise level (fraction, 1 sigma): drawn as a grey band +-noise.
    """
    x = np.asarray(x_m, dtype=float).ravel()
    scale = 100.0 if percent else 1.0
    band = None if noise is None else (-scale * noise, scale * noise, "noise (1 sigma)")
    panels = []
    for prefix, idx in _pass_rows(passes, len(x)):
        order = idx[np.argsort(x[idx], kind="stable")]
        for j, k in enumerate(receivers):
            series = []
            for m, (name, e) in enumerate(errors.items()):
                low = name.lower()
                style = "--" if ("vs bem" in low or "/ bem" in low) else ("-." if "corrected" in low else "-")
                series.append(Series(x[order], scale * np.asarray(e, dtype=float)[order, j], name, "line",
                                     colour_of(name, m), style=style))
            label = y_label if percent or not y_label.endswith("(%)") else y_label[:-4]
            panels.append(Panel(f"{title_prefix}{prefix}receiver {k}", x_label, label, series, zero_line=True,
                                band=band))
    span = _common_range([s.y for p in panels for s in p.series] + ([np.array(band[:2])] if band else []))
    for p in panels:
        p.y_range = span
    return curves_figure(panels, png_path, ncols=len(receivers))


# ------------------------------------------------------------------ 3D figures
def _pv():
    """pyvista, once an offscreen backend is chosen (:class:`electrosense.meshes.render.RenderUnavailable` without one)."""
    from electrosense.meshes.render import require_3d

    require_3d()
    import pyvista

    return pyvista


def _polydata(mesh):
    pv = _pv()
    faces = np.hstack([np.full((mesh.faces.shape[0], 1), 3), mesh.faces]).ravel()
    poly = pv.PolyData(np.asarray(mesh.vertices_m, dtype=float), faces)
    poly.cell_data["electrode"] = np.asarray(mesh.electrode)
    return poly


def _add_sensor(plotter, sensor_mesh, pose=None, emitter=None):
    """Sensor faces: grey insulator, one colour per electrode (those of :mod:`electrosense.meshes.render`, so that
    every picture of a sensor agrees); returns the legend entries."""
    from electrosense.meshes.render import electrode_colour, electrode_legend

    mesh = sensor_mesh.transformed(pose) if pose is not None else sensor_mesh
    poly = _polydata(mesh)
    labels = np.asarray(mesh.electrode)
    present = [int(k) for k in np.unique(labels)]
    for k in present:
        edge = "#a0a0a0" if k == 0 else "#404040"
        plotter.add_mesh(poly.extract_cells(np.flatnonzero(labels == k)), color=electrode_colour(k, emitter), show_edges=True,
                         edge_color=edge, line_width=0.5)
    return [list(entry) for entry in electrode_legend([k for k in present if k > 0], emitter)]


def _scalar_bar(title: str, fmt: str = "%.2f") -> dict:
    # vertical, at the panel's right edge: its title above, its labels beside it (a horizontal bar in VTK
    # writes both above the bar, where they overlap)
    return {"title": title + "\n", "title_font_size": 20, "label_font_size": 18, "color": "black", "vertical": True,
            "position_x": 0.82, "position_y": 0.12, "height": 0.6, "width": 0.07, "fmt": fmt, "n_labels": 5}


def scene_figure(
    png_path,
    sensor_mesh=None,
    pose=None,
    tank=None,
    trajectory_m=None,
    values=None,
    value_label: str = "mean abs. relative error (%)",
    object_meshes=(),
    title: str = "",
    window_size=(1800, 900),
    passes=None,
    emitter: int | None = None,
    value_floor: float = 0.0,
) -> Path:
    """The 3D scene: tank, sensor mesh (electrodes coloured), path coloured by ``values``.

    Left: the whole tank with the path (a tube coloured by ``values``) and the
    sensor drawn at ``pose``, true size. Right: a close-up of the sensor mesh
    with its electrodes coloured and named.

    Parameters
    ----------
    sensor_mesh : meshes.labelled_mesh.LabelledMesh, optional
        Sensor mesh in the SENSOR frame; drawn at ``pose`` (a meshes.pose.Pose).
    tank : meshes.tank.Tank, optional
        Drawn as the edges of the water box with a translucent floor.
    trajectory_m : (P, 3) array, optional
        Sensor centres along the path (tank frame).
    values : (P,) array, optional
        Scalar per pose for the path's colour map (e.g. error in %).
    object_meshes : sequence of LabelledMesh
        Objects in the tank frame.
    passes : (P,) array, optional
        Pass labels: each pass is drawn as its own line.
    emitter : int, optional
        1-based emitter, named in the sensor's legend.
    value_floor : float
        The colour scale of ``values`` runs from 0 to at least this (e.g. the
        noise level), so that noise is not stretched into structure.
    """
    pv = _pv()
    has_closeup = sensor_mesh is not None
    plotter = pv.Plotter(off_screen=True, window_size=window_size, shape=(1, 2) if has_closeup else (1, 1), border=False)
    plotter.set_background("white")
    legend = []
    if isinstance(tank, CylinderTank):   # a round tank: its water's rims and four generatrices
        z0, z1 = tank.floor_z_m, tank.free_surface_z_m
        r0, r1 = float(tank.radius_at(z0)), float(tank.radius_at(z1))
        turn = np.linspace(0.0, 2 * np.pi, 121)
        rims = [np.c_[r * np.cos(turn), r * np.sin(turn), np.full_like(turn, z)] for r, z in ((r0, z0), (r1, z1))]
        sides = [np.array([[r0 * np.cos(a), r0 * np.sin(a), z0], [r1 * np.cos(a), r1 * np.sin(a), z1]])
                 for a in np.arange(4) * np.pi / 2]
        for line in rims + sides:
            plotter.add_mesh(pv.lines_from_points(line), color="#305080", line_width=3)
        plotter.add_mesh(pv.Disc(center=(0.0, 0.0, z0), inner=0.0, outer=r0, c_res=120), color="#9fb8d8",
                         opacity=0.35)
        legend.append(["tank (water)", "#305080"])
    elif tank is not None:
        lo, hi = tank.water_bounds_m
        box = pv.Box(bounds=(lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]))
        plotter.add_mesh(box.extract_feature_edges(), color="#305080", line_width=3)
        floor = pv.Plane(center=(0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), lo[2]),
                         i_size=hi[0] - lo[0], j_size=hi[1] - lo[1])
        plotter.add_mesh(floor, color="#9fb8d8", opacity=0.35)
        legend.append(["tank (water box)", "#305080"])
    for mesh in object_meshes:
        plotter.add_mesh(_polydata(mesh), color="#6b8e23")
    if object_meshes:
        legend.append(["objects", "#6b8e23"])
    if sensor_mesh is not None:
        mesh = sensor_mesh.transformed(pose) if pose is not None else sensor_mesh
        plotter.add_mesh(_polydata(mesh), color="#444444")
        legend.append(["sensor", "#444444"])
    if trajectory_m is not None:
        pts = np.atleast_2d(np.asarray(trajectory_m, dtype=float))
        path = pv.PolyData(pts)
        cells = [np.concatenate([[len(idx)], idx]) for idx in _segments(passes, len(pts)) if len(idx) > 1]
        if cells:
            path.lines = np.concatenate(cells)
        if values is not None:
            path.point_data[value_label] = np.asarray(values, dtype=float).ravel()
            tube = path.tube(radius=0.006) if cells else path
            v = path.point_data[value_label]
            top = max(float(np.nanmax(v)) if np.isfinite(v).any() else 0.0, float(value_floor)) or 1.0
            decimals = max(2, int(np.ceil(-np.log10(top / 4))) + 1)   # five labels that differ
            plotter.add_mesh(tube, scalars=value_label, cmap="viridis", clim=(0.0, top),
                             scalar_bar_args=_scalar_bar(value_label, f"%.{decimals}f"))
        else:
            plotter.add_mesh(path, color="black", line_width=4)
            legend.append(["sensor path", "black"])
    if legend:
        plotter.add_legend(legend, bcolor="white", border=True, size=(0.3, 0.05 * len(legend) + 0.02),
                           loc="upper left", face="rectangle")
    if title:
        plotter.add_text(title, position="upper_right", font_size=14, color="black")
    plotter.show_axes()
    plotter.camera_position = [(1.6, -2.2, 1.3), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)]
    plotter.reset_camera()
    plotter.camera.zoom(0.9)
    plotter.camera.elevation = 4.0
    if has_closeup:
        plotter.subplot(0, 1)
        legend = _add_sensor(plotter, sensor_mesh, emitter=emitter)
        plotter.add_legend(legend, bcolor="white", border=True, size=(0.36, 0.05 * len(legend) + 0.02),
                           loc="upper left", face="rectangle")
        length = float(np.ptp(sensor_mesh.vertices_m[:, 0]))
        plotter.add_text(f"sensor mesh: {sensor_mesh.n_triangles} triangles, {length * 100:.1f} cm, head (1) at +x",
                         position="lower_edge", font_size=14, color="black")
        from electrosense.meshes.render import facing_emitter

        plotter.view_vector(facing_emitter(sensor_mesh, emitter, base=(0.35, -1.0, 0.45)), viewup=(0.0, 0.0, 1.0))
        plotter.reset_camera()
        plotter.camera.zoom(0.92)
    png_path = Path(png_path)
    png_path.parent.mkdir(parents=True, exist_ok=True)
    plotter.screenshot(str(png_path))
    plotter.close()
    return png_path


def current_lines(x_m, y_m, field_V_per_m, seeds_m, step_m: float | None = None, max_steps: int = 3000) -> list:
    """Field lines of a 2D vector field on a grid, traced from seed points along the field (RK2).

    A line stops where the field is undefined (NaN: inside a body), off the
    grid, or where the field vanishes. Returns a list of (k, 2) arrays.
    """
    from scipy.interpolate import RegularGridInterpolator

    x = np.asarray(x_m, dtype=float)
    y = np.asarray(y_m, dtype=float)
    F = np.asarray(field_V_per_m, dtype=float)
    interp = [RegularGridInterpolator((y, x), F[..., c], bounds_error=False, fill_value=np.nan) for c in (0, 1)]
    step = step_m or 0.5 * min(np.diff(x).min(), np.diff(y).min())

    def direction(p):
        v = np.array([interp[0](p[::-1])[0], interp[1](p[::-1])[0]])
        norm = np.hypot(*v)
        return None if not np.isfinite(norm) or norm == 0 else v / norm

    lines = []
    for seed in np.atleast_2d(np.asarray(seeds_m, dtype=float)):
        p = seed.copy()
        pts = [p.copy()]
        for _ in range(max_steps):
            d1 = direction(p)
            if d1 is None:
                break
            d2 = direction(p + 0.5 * step * d1)
            if d2 is None:
                break
            p = p + step * d2
            pts.append(p.copy())
        if len(pts) > 2:
            lines.append(np.array(pts))
    return lines


def _fill_outside(values: np.ndarray) -> np.ndarray:
    """NaN cells given the value of the nearest finite cell (so that colours run smoothly up to a body's outline)."""
    from scipy.ndimage import distance_transform_edt

    missing = ~np.isfinite(values)
    if not missing.any():
        return values
    _, (iy, ix) = distance_transform_edt(missing, return_indices=True)
    return values[iy, ix]


def potential_figure(
    png_path,
    x_m,
    y_m,
    potential_V,
    sensor_outline_m=None,
    electrode_segments=(),
    seeds_m=None,
    walls_m=(),
    title: str = "",
    window_size=(7.0, 3.9),
    n_isolines: int = 16,
    emitter: int | None = None,
) -> Path:
    """Potential on a horizontal plane (colour map and equipotentials) with current lines.

    The sensor is drawn by its exact outline (filled, over the map), so that
    the grid cells left NaN inside it never show as blocks; the colours run
    smoothly up to the outline.

    Parameters
    ----------
    x_m, y_m : (nx,), (ny,) arrays
        Grid lines of the plane (tank frame), metres.
    potential_V : (ny, nx) array
        Potential at the grid points; NaN inside the sensor.
    sensor_outline_m : (k, 2) array, optional
        Closed polygon of the sensor's cut by the plane.
    electrode_segments : sequence of ((k, 2) array, label)
        The electrodes' traces on the outline (electrode k is the k-th),
        coloured as in :mod:`electrosense.meshes.render` and named in the legend.
    seeds_m : (s, 2) array, optional
        Start points of the current lines (e.g. around the emitter); the lines
        follow E = -grad(potential), the direction of the current density.
    walls_m : sequence of (2, 2) arrays
        Insulating tank walls crossing the picture, drawn as thick lines.
    window_size : (float, float)
        Inches (or pixels of the PNG when larger than 40).
    emitter : int, optional
        The emitter electrode (its colour); default: read from the labels.
    """
    from matplotlib.patches import Polygon

    from electrosense.meshes.render import electrode_colour

    x = np.asarray(x_m, dtype=float)
    y = np.asarray(y_m, dtype=float)
    phi = np.asarray(potential_V, dtype=float)
    if phi.shape != (y.size, x.size):
        raise ValueError(f"potential has shape {phi.shape}, expected (ny, nx) = {(y.size, x.size)}")
    finite = phi[np.isfinite(phi)]
    if finite.size == 0:
        raise ValueError("the potential has no finite value to draw")
    gy, gx = np.gradient(phi, y, x)  # NaN next to the body: lines stop there
    E = np.stack([-gx, -gy], axis=-1)
    lo, hi = np.percentile(finite, [1, 99])
    if hi <= lo:
        lo, hi = lo - 0.5, hi + 0.5
    smooth = _fill_outside(phi)
    fig, axes = new_figure(1, 1, _px_to_in(window_size))
    ax = axes[0, 0]
    ax.grid(False)
    image = ax.pcolormesh(x, y, smooth, shading="gouraud", cmap="viridis", vmin=lo, vmax=hi, rasterized=True,
                          zorder=0)
    fig.colorbar(image, ax=ax, label="potential (V)", shrink=0.9, pad=0.02)
    handles = []
    from matplotlib.lines import Line2D

    levels = np.linspace(lo, hi, n_isolines)[1:-1]
    ax.contour(x, y, smooth, levels=levels, colors="white", linewidths=0.5, alpha=0.8, zorder=1)
    from matplotlib.patheffects import withStroke

    handles.append(Line2D([], [], color="white", lw=0.8, label="equipotentials",
                          path_effects=[withStroke(linewidth=2.2, foreground="#6a6a6a")]))
    if seeds_m is not None:
        lines = current_lines(x, y, E, seeds_m)
        for line in lines:
            ax.plot(line[:, 0], line[:, 1], color="black", lw=0.8, zorder=2)
            mid = len(line) // 2
            if mid + 1 < len(line):
                ax.annotate("", line[mid + 1], line[mid], zorder=2,
                            arrowprops=dict(arrowstyle="-|>", color="black", lw=0.6, mutation_scale=7))
        if lines:
            handles.append(Line2D([], [], color="black", lw=0.8, label="current lines"))
    if sensor_outline_m is not None:
        ax.add_patch(Polygon(np.asarray(sensor_outline_m, dtype=float), closed=True, facecolor="#d0d0d0",
                             edgecolor="#606060", lw=0.8, zorder=3))
        handles.append(Polygon([[0, 0]], facecolor="#d0d0d0", edgecolor="#606060", label="sensor (insulating)"))
    for wall in walls_m:
        wall = np.asarray(wall, dtype=float)
        ax.plot(wall[:, 0], wall[:, 1], color="#1b2a49", lw=4, solid_capstyle="butt", zorder=4)
    if len(walls_m):
        handles.append(Line2D([], [], color="#1b2a49", lw=4, label="tank wall (insulating)"))
    segments = list(electrode_segments)
    if emitter is None:
        emitter = next((k for k, (_, label) in enumerate(segments, 1) if "emitter" in str(label)), None)
    for k, (seg, label) in enumerate(segments, start=1):
        colour = electrode_colour(k, emitter)
        seg = np.asarray(seg, dtype=float)
        ax.plot(seg[:, 0], seg[:, 1], color=colour, lw=3.5, solid_capstyle="butt", zorder=5)  # NaN breaks a ring
        handles.append(Line2D([], [], color=colour, lw=3.5, label=label))
    ax.set_xlim(x[0], x[-1])
    ax.set_ylim(y[0], y[-1])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    if title:
        ax.set_title(title)
    # three columns: four labels of "electrode k (receiver)" length overflow the figure's width
    fig.legend(handles=handles, loc="outside lower center", ncols=min(len(handles), 3))
    return save(fig, png_path)


def png_is_blank(png_path, tolerance: int = 0) -> bool:
    """True when every pixel of the image is (nearly) the same colour."""
    from matplotlib.image import imread

    img = np.asarray(imread(str(png_path)))
    if img.dtype != np.uint8:
        img = np.round(255 * img).astype(int)
    img = img.reshape(-1, img.shape[-1]) if img.ndim == 3 else img.reshape(-1, 1)
    return bool(np.all(np.ptp(img.astype(int), axis=0) <= tolerance))
