"""Figures of the validation and diagnosis reports, drawn with pyvista offscreen.

Two kinds of figures:

* 2D curves (:func:`curves_figure`, :func:`bar_figure`) on pyvista's
  ``Chart2D``: a grid of panels, each a list of :class:`Series`; the
  report-specific figures (:func:`resistance_figure`,
  :func:`relative_error_figure`) are thin layers over it, and the gap
  diagnosis reuses the same pieces.
* 3D scenes (:func:`scene_figure`, :func:`potential_figure`): the tank, the
  sensor mesh with its electrodes coloured, the trajectory coloured by a value,
  and the potential on a plane with current lines.

Every function takes plain arrays (and meshes), writes one PNG and returns its
path. Fonts are sized for a printed page; axes carry their units.

Example
-------
>>> import numpy as np, tempfile, os
>>> x = np.linspace(-0.4, 0.4, 20)
>>> panel = Panel("receiver 1", "x (m)", "U/I (ohm)", [Series(x, 600 + 500 * x**2, "bench")])
>>> path = curves_figure([panel], os.path.join(tempfile.mkdtemp(), "r.png"))
>>> path.exists()
True
"""
from __future__ import annotations

import os

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkOSOpenGLRenderWindow")

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
import pyvista as pv

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

#: Colours of the usual series, the same in every figure.
COLOURS = {
    "bench": "black",
    "bench (corrected)": "#8c8c8c",
    "bem": "#1f5fbf",
    "psm": "#d9541a",
    "bem-psm": "#6a3d9a",
    "psm vs bem": "#6a3d9a",
}
_CYCLE = ["#1f5fbf", "#d9541a", "#2ca02c", "#6a3d9a", "#b8860b", "#17becf", "#e377c2", "#7f7f7f"]

FONT = {"title": 26, "label": 22, "ticks": 18, "legend": 18}
PANEL_SIZE = (760, 560)


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
    width: float = 3.0
    marker_size: float = 9.0
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
    """One chart: a title, axis labels with units, and its series."""

    title: str
    x_label: str
    y_label: str
    series: list[Series] = field(default_factory=list)
    y_range: tuple[float, float] | None = None
    x_range: tuple[float, float] | None = None
    legend_loc: str = "upper right"
    headroom: float = 0.3
    """Fraction of the data's height left free above it for the legend (when ``y_range`` is not set)."""


def _colour(name: str, k: int) -> str:
    """The usual colour of a series named ``name`` (or of its first word), else the k-th of a cycle."""
    key = name.lower()
    if key in COLOURS:
        return COLOURS[key]
    first = key.split()[0] if key.split() else key
    return COLOURS.get(first, _CYCLE[k % len(_CYCLE)])


def _padded_range(values: Sequence[np.ndarray], pad: float = 0.05) -> tuple[float, float] | None:
    finite = [v[np.isfinite(v)] for v in values if v.size]
    finite = [v for v in finite if v.size]
    if not finite:
        return None
    lo = min(float(v.min()) for v in finite)
    hi = max(float(v.max()) for v in finite)
    span = hi - lo
    if span <= 0:
        span = abs(hi) if hi != 0 else 1.0
    return lo - pad * span, hi + pad * span


_LEGEND_ALIGN = {"left": 0, "centre": 1, "center": 1, "right": 2, "upper": 3, "top": 3, "lower": 4, "bottom": 4}


def _chart(panel: Panel) -> "pv.Chart2D":
    chart = pv.Chart2D(x_label=panel.x_label, y_label=panel.y_label)
    chart.background_color = "white"
    chart.title = panel.title
    chart.GetTitleProperties().SetFontSize(FONT["title"])
    for axis in (chart.x_axis, chart.y_axis):
        axis.label_size = FONT["label"]
        axis.tick_label_size = FONT["ticks"]
    chart.GetLegend().SetLabelSize(FONT["legend"])
    # leave room for the tick labels and the axis titles
    chart.loc = (0.04, 0.05)
    chart.size = (0.94, 0.92)
    for s in panel.series:
        if s.kind == "line":
            chart.line(s.x, s.y, color=s.colour or "black", width=s.width, label=s.label, style=s.style)
        else:
            chart.scatter(s.x, s.y, color=s.colour or "black", size=s.marker_size, style=s.marker, label=s.label)
    chart.legend_visible = any(s.label for s in panel.series)
    try:
        vertical, horizontal = panel.legend_loc.split()
        legend = chart.GetLegend()
        legend.SetVerticalAlignment(_LEGEND_ALIGN[vertical])
        legend.SetHorizontalAlignment(_LEGEND_ALIGN[horizontal])
    except (ValueError, KeyError):
        raise ValueError(f"panel {panel.title!r}: legend_loc {panel.legend_loc!r} is not like 'upper right'") from None
    y_range = panel.y_range or _padded_range([s.y for s in panel.series])
    if panel.y_range is None and y_range is not None and chart.legend_visible:
        y_range = (y_range[0], y_range[1] + panel.headroom * (y_range[1] - y_range[0]))
    x_range = panel.x_range or _padded_range([s.x for s in panel.series], pad=0.0)
    if y_range is not None:
        chart.y_range = list(y_range)
    if x_range is not None and x_range[1] > x_range[0]:
        chart.x_range = list(x_range)
    return chart


def curves_figure(panels: Sequence[Panel], png_path, ncols: int | None = None, panel_size=PANEL_SIZE) -> Path:
    """Draw panels of 2D curves on a grid (``ncols`` per row) and save a PNG.

    Parameters
    ----------
    panels : sequence of Panel
    png_path : path-like
    ncols : int, optional
        Panels per row (default: all in one row up to 3).
    panel_size : (int, int)
        Pixels per panel.
    """
    panels = list(panels)
    if not panels:
        raise ValueError("curves_figure needs at least one panel")
    ncols = ncols or min(len(panels), 3)
    nrows = math.ceil(len(panels) / ncols)
    plotter = pv.Plotter(
        off_screen=True,
        shape=(nrows, ncols),
        border=False,
        window_size=(panel_size[0] * ncols, panel_size[1] * nrows),
    )
    plotter.set_background("white")
    for i, panel in enumerate(panels):
        plotter.subplot(i // ncols, i % ncols)
        plotter.add_chart(_chart(panel))
    png_path = Path(png_path)
    png_path.parent.mkdir(parents=True, exist_ok=True)
    plotter.screenshot(str(png_path))
    plotter.close()
    return png_path


def bar_figure(categories: Sequence[str], values: dict, png_path, title: str, y_label: str, panel_size=(900, 560),
               y_max: float | None = None) -> Path:
    """Grouped bars: one group per category, one bar colour per key of ``values``.

    The categories are written on the x axis as tick labels (``_`` breaks the
    line, so identifiers such as ``contact_impedance`` stay readable). Bars
    above ``y_max`` are cut there and their value is written under the
    category, so that one off-scale bar does not flatten the others.

    Parameters
    ----------
    categories : sequence of str
        Names on the x axis (e.g. regions of the path).
    values : dict
        Label -> (len(categories),) array (e.g. model -> mean |error| in %).
    """
    categories = [str(c).replace("_", "\n") for c in categories]
    if not categories or not values:
        raise ValueError("bar_figure needs categories and at least one series of values")
    x = np.arange(len(categories), dtype=float)
    arrays, labels, colours = [], [], []
    for k, (label, v) in enumerate(values.items()):
        v = np.asarray(v, dtype=float).ravel()
        if v.size != len(categories):
            raise ValueError(f"bar series {label!r} has {v.size} values for {len(categories)} categories")
        if y_max is not None:
            for i in np.flatnonzero(v > y_max):
                categories[i] += f"\n({label.split(' (')[0]} {v[i]:.3g})"
            v = np.minimum(v, y_max)
        arrays.append(v)
        labels.append(str(label))
        colour = _colour(str(label), k)
        spare = (c for c in _CYCLE if c not in colours)
        colours.append(colour if colour not in colours else next(spare, colour))  # every bar series distinct
    chart = _chart(Panel(title, "", y_label, []))
    for v, label, colour in zip(arrays, labels, colours):
        chart.bar(x, v, color=colour, label=label)  # VTK places the bar plots of one chart side by side
    chart.legend_visible = True
    top = max(float(np.nanmax(a)) for a in arrays)
    bottom = min(0.0, min(float(np.nanmin(a)) for a in arrays))
    chart.y_range = [bottom, top * 1.3 if top > 0 else 1.0]
    chart.x_range = [-0.6, len(categories) - 0.4]
    chart.x_axis.tick_locations = x
    chart.x_axis.tick_labels = categories
    plotter = pv.Plotter(off_screen=True, window_size=panel_size)
    plotter.set_background("white")
    plotter.add_chart(chart)
    png_path = Path(png_path)
    png_path.parent.mkdir(parents=True, exist_ok=True)
    plotter.screenshot(str(png_path))
    plotter.close()
    return png_path


# ---------------------------------------------------------------- path helpers
def path_coordinate(poses) -> tuple[np.ndarray, str]:
    """The abscissa for plots along a path: x, y, or the arc length (m), with its label.

    x (or y) when the path runs mainly along it (its range is at least 5 times
    the others'), otherwise the distance travelled.
    """
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
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
        out.append(Series(x[order], values[order], name if i == 0 else "", kind=kind, colour=_colour(name, k)))
    return out


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

    The paper's figures 6 to 8 (x in m, resistance in ohm), one panel per receiver.

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
        Pass labels: model curves are drawn pass by pass.
    """
    x = np.asarray(x_m, dtype=float).ravel()
    panels = []
    for j, k in enumerate(receivers):
        series = []
        for m, (name, R) in enumerate(models_ohm.items()):
            series += _model_series(x, np.asarray(R, dtype=float)[:, j], name.upper(), m, passes)
        if corrected_bench_ohm is not None:
            series.append(Series(x, np.asarray(corrected_bench_ohm)[:, j], "bench (corrected)", "scatter",
                                 COLOURS["bench (corrected)"], marker_size=7, marker="d"))
        if bench_ohm is not None:
            series.append(Series(x, np.asarray(bench_ohm)[:, j], "bench", "scatter", COLOURS["bench"], marker_size=7))
        panels.append(Panel(f"{title_prefix}receiver {k}", x_label, "resistance U/I (ohm)", series, legend_loc="upper centre"))
    return curves_figure(panels, png_path)


def relative_error_figure(
    x_m,
    errors: dict,
    receivers: Sequence[int],
    png_path,
    x_label: str = "sensor position x (m)",
    passes=None,
    title_prefix: str = "",
    percent: bool = True,
) -> Path:
    """Relative error against position, one panel per receiver, one curve per comparison.

    Curves are coloured by model (the first word of the label); comparisons
    against the BEM are dashed, those after a conductivity correction
    ("corrected" in the label) dash-dotted.

    Parameters
    ----------
    errors : dict
        Label (e.g. ``"BEM vs bench"``) -> (P, m) relative errors (fractions).
    percent : bool
        Plot in percent (default).
    """
    x = np.asarray(x_m, dtype=float).ravel()
    scale = 100.0 if percent else 1.0
    panels = []
    for j, k in enumerate(receivers):
        series = []
        for m, (name, e) in enumerate(errors.items()):
            style = "--" if name.lower().endswith("vs bem") else ("-." if "corrected" in name.lower() else "-")
            for s in _model_series(x, scale * np.asarray(e, dtype=float)[:, j], name, m, passes):
                s.style = style
                series.append(s)
        series.append(Series([x.min(), x.max()], [0.0, 0.0], "", "line", "#444444", width=1.0))
        unit = "relative error (%)" if percent else "relative error"
        panels.append(Panel(f"{title_prefix}receiver {k}", x_label, unit, series))
    return curves_figure(panels, png_path)


# ------------------------------------------------------------------ 3D figures
def _polydata(mesh) -> "pv.PolyData":
    faces = np.hstack([np.full((mesh.faces.shape[0], 1), 3), mesh.faces]).ravel()
    poly = pv.PolyData(np.asarray(mesh.vertices_m, dtype=float), faces)
    poly.cell_data["electrode"] = np.asarray(mesh.electrode)
    return poly


def _add_sensor(plotter, sensor_mesh, pose=None, emitter=None):
    """Sensor faces: grey insulator, one colour per electrode (those of :mod:`meshes.render`, so that
    every picture of a sensor agrees); returns the legend entries."""
    from meshes.render import electrode_colour, electrode_legend

    mesh = sensor_mesh.transformed(pose) if pose is not None else sensor_mesh
    poly = _polydata(mesh)
    labels = np.asarray(mesh.electrode)
    present = [int(k) for k in np.unique(labels)]
    for k in present:
        edge = "#a0a0a0" if k == 0 else "#404040"
        plotter.add_mesh(poly.extract_cells(np.flatnonzero(labels == k)), color=electrode_colour(k), show_edges=True,
                         edge_color=edge, line_width=0.5)
    return [list(entry) for entry in electrode_legend([k for k in present if k > 0], emitter)]


def _scalar_bar(title: str, fmt: str = "%.2f") -> dict:
    return {"title": title, "title_font_size": 22, "label_font_size": 20, "color": "black", "vertical": False,
            "position_x": 0.2, "position_y": 0.03, "height": 0.06, "width": 0.6, "fmt": fmt, "n_labels": 5}


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
    """
    has_closeup = sensor_mesh is not None
    plotter = pv.Plotter(off_screen=True, window_size=window_size, shape=(1, 2) if has_closeup else (1, 1), border=False)
    plotter.set_background("white")
    legend = []
    if tank is not None:
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
            plotter.add_mesh(tube, scalars=value_label, cmap="viridis", scalar_bar_args=_scalar_bar(value_label))
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
        plotter.camera_position = [(0.0, -1.0, 0.45), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)]
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
    window_size=(1700, 820),
    n_isolines: int = 16,
) -> Path:
    """Potential on a horizontal plane (colour map and equipotentials) with current lines.

    Parameters
    ----------
    x_m, y_m : (nx,), (ny,) arrays
        Grid lines of the plane (tank frame), metres.
    potential_V : (ny, nx) array
        Potential at the grid points; NaN inside the sensor (left blank).
    sensor_outline_m : (k, 2) array, optional
        Closed polygon of the sensor's cut by the plane.
    electrode_segments : sequence of ((k, 2) array, label)
        The electrodes' traces on the outline, coloured and named in the legend.
    seeds_m : (s, 2) array, optional
        Start points of the current lines (e.g. around the emitter); the lines
        follow E = -grad(potential), the direction of the current density.
    walls_m : sequence of (2, 2) arrays
        Insulating tank walls crossing the picture, drawn as thick lines.
    """
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
    grid = pv.RectilinearGrid(x, y, np.array([0.0]))
    grid.point_data["potential (V)"] = phi.ravel()
    plotter = pv.Plotter(off_screen=True, window_size=window_size)
    plotter.set_background("white")
    lo, hi = np.percentile(finite, [1, 99])
    plotter.add_mesh(
        grid, scalars="potential (V)", cmap="coolwarm", clim=(lo, hi), nan_opacity=0.0,
        scalar_bar_args={"title": "potential (V)", "title_font_size": 24, "label_font_size": 20,
                         "color": "black", "vertical": True, "position_x": 0.87, "position_y": 0.12,
                         "height": 0.72, "width": 0.05, "fmt": "%.2f"},
    )
    lift = 1e-3 * max(np.ptp(x), np.ptp(y))  # draw lines just above the coloured plane
    legend = []
    filled = grid.copy()
    filled.point_data["potential (V)"] = np.where(np.isfinite(phi), phi, np.nanmax(phi) + 10 * (hi - lo)).ravel()
    contours = filled.contour(isosurfaces=np.linspace(lo, hi, n_isolines)[1:-1], scalars="potential (V)")
    if contours.n_points:
        contours.points[:, 2] += lift
        plotter.add_mesh(contours, color="#505050", line_width=1.5)
        legend.append(["equipotentials", "#505050"])
    if seeds_m is not None:
        lines = current_lines(x, y, E, seeds_m)
        if lines:
            for line in lines:
                pts = np.column_stack([line, np.full(len(line), 2 * lift)])
                plotter.add_mesh(pv.lines_from_points(pts), color="black", line_width=2.5)
            legend.append(["current lines", "black"])
    if sensor_outline_m is not None:
        o = np.asarray(sensor_outline_m, dtype=float)
        pts = np.column_stack([o, np.full(len(o), 3 * lift)])
        plotter.add_mesh(pv.lines_from_points(np.vstack([pts, pts[:1]])), color="#808080", line_width=4)
        legend.append(["sensor (insulating)", "#808080"])
    for wall in walls_m:
        pts = np.column_stack([np.asarray(wall, dtype=float), np.full(2, 3 * lift)])
        plotter.add_mesh(pv.lines_from_points(pts), color="#1b2a49", line_width=10)
    if len(walls_m):
        legend.append(["tank wall (insulating)", "#1b2a49"])
    from meshes.render import electrode_colour

    for k, (seg, label) in enumerate(electrode_segments, start=1):
        colour = electrode_colour(k)
        seg = np.asarray(seg, dtype=float)
        for piece in np.split(seg, np.flatnonzero(np.isnan(seg[:, 0]))):
            piece = piece[np.isfinite(piece[:, 0])]
            if len(piece) > 1:
                pts = np.column_stack([piece, np.full(len(piece), 4 * lift)])
                plotter.add_mesh(pv.lines_from_points(pts), color=colour, line_width=9)
        legend.append([label, colour])
    if legend:
        plotter.add_legend(legend, bcolor="white", border=True, size=(0.17, 0.045 * len(legend) + 0.02),
                           loc="upper left", face="rectangle")
    if title:
        plotter.add_text(title, position="upper_edge", font_size=16, color="black")
    plotter.show_bounds(xtitle="x (m)", ytitle="y (m)", font_size=20, color="black", location="outer",
                        grid=False, ticks="outside", n_xlabels=5, n_ylabels=5, fmt="%.2f", show_zaxis=False,
                        show_zlabels=False, bounds=(x[0], x[-1], y[0], y[-1], 0.0, 0.0))
    plotter.view_xy()
    plotter.camera.zoom(1.25)
    shift = -0.07 * (x[-1] - x[0])  # make room on the left for the legend
    cam = plotter.camera
    cam.focal_point = (cam.focal_point[0] + shift, *cam.focal_point[1:])
    cam.position = (cam.position[0] + shift, *cam.position[1:])
    png_path = Path(png_path)
    png_path.parent.mkdir(parents=True, exist_ok=True)
    plotter.screenshot(str(png_path))
    plotter.close()
    return png_path


def png_is_blank(png_path, tolerance: int = 0) -> bool:
    """True when every pixel of the image is (nearly) the same colour."""
    img = np.asarray(pv.read(str(png_path)).point_data.active_scalars)
    if img.ndim == 1:
        img = img[:, None]
    return bool(np.all(np.ptp(img.astype(int), axis=0) <= tolerance))
