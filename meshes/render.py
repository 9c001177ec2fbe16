"""Offscreen pictures of labelled meshes, fit for a report.

The emitter is drawn in gold (:data:`EMITTER_COLOUR`, a colour no receiver
gets) and faces the camera; the receivers in distinct colours; a legend names
them ("electrode 4 (emitter)"), the insulator in grey, the tank's water box translucent, the
objects in bronze; the axes are labelled in metres. For a scene the sensor
is small next to the tank, so the picture gets a second panel, a close-up
of the sensor.

Example
-------
>>> import tempfile, pathlib
>>> from electrosense.meshes import preset
>>> from electrosense.meshes.sensor_mesh import mesh_sensor
>>> from electrosense.meshes.render import render_mesh
>>> png = pathlib.Path(tempfile.mkdtemp()) / "sensor.png"
>>> render_mesh(mesh_sensor(preset("angels-4")), png, title="angels-4").exists()
True

Offscreen rendering
-------------------
VTK renders without a display through EGL (GPU or Mesa's EGL) or OSMesa
(software), whichever the machine has. :func:`offscreen_backend` chooses once
per process (a trial render in a subprocess, so that a missing library that
crashes VTK cannot crash the caller), sets ``VTK_DEFAULT_OPENGL_WINDOW`` for
this process and its children, and returns the choice; :func:`can_render_3d`
says whether any works. The environment variable
``ESENSE_OFFSCREEN_BACKEND`` (``egl``, ``osmesa`` or ``none``) skips the trial.
With neither, the 3D pictures raise :class:`RenderUnavailable`, whose message
says what to install; reports leave those pictures out and say so.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from electrosense.meshes.cylinder_tank import CYLINDER_TANK_REGIONS
from electrosense.meshes.labelled_mesh import LabelledMesh
from electrosense.meshes.tank import TANK_REGIONS

__all__ = ["offscreen_backend", "can_render_3d", "RenderUnavailable", "require_3d", "render_mesh", "mesh_plotter", "render_data", "data_plotter", "ELECTRODE_COLOURS", "EMITTER_COLOUR", "INSULATOR_COLOUR",
           "electrode_colour", "facing_emitter", "electrode_legend"]

#: receivers' colours: distinct from the insulator's grey, the water's blue and the emitter's gold
ELECTRODE_COLOURS = ("#d62728", "#1f77b4", "#2ca02c", "#9467bd", "#e377c2", "#17becf", "#8c564b", "#7f7f00")
#: the emitter's colour in every picture (never a receiver's)
EMITTER_COLOUR = "#f2b700"
INSULATOR_COLOUR = "#9a9a9a"
TANK_COLOUR = "#6fa8dc"
FREE_SURFACE_COLOUR = "#3d85c6"
OBJECT_COLOUR = "#c08a45"
BACKGROUND = "white"

_TANK_REGIONS = set(TANK_REGIONS) | set(CYLINDER_TANK_REGIONS)


def _parts(names) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Masks of a mesh's faces by region: tank (box or cylinder), objects, the sensor's body (neither, nor an
    electrode in the water, region ``electrode_<k>``)."""
    names = names.astype(str)
    is_tank = np.isin(names, list(_TANK_REGIONS))
    is_object = np.char.startswith(names, "object")
    return is_tank, is_object, ~is_tank & ~is_object & ~np.char.startswith(names, "electrode_")


#: offscreen backends in the order tried: name -> VTK render window class
OFFSCREEN_BACKENDS = {"egl": "vtkEGLRenderWindow", "osmesa": "vtkOSOpenGLRenderWindow"}
_ENV = "ESENSE_OFFSCREEN_BACKEND"
_chosen: list = []  # [name or None] once probed in this process

# A trial render: an 8 x 8 red window; prints the class VTK really made (it falls back silently) and the pixel.
_PROBE = """
from vtkmodules.vtkCommonCore import vtkUnsignedCharArray
from vtkmodules.vtkRenderingCore import vtkRenderWindow, vtkRenderer
import vtkmodules.vtkRenderingOpenGL2
window = vtkRenderWindow()
window.SetOffScreenRendering(1)
window.SetSize(8, 8)
renderer = vtkRenderer()
renderer.SetBackground(1.0, 0.0, 0.0)
window.AddRenderer(renderer)
window.Render()
pixel = vtkUnsignedCharArray()
window.GetPixelData(0, 0, 0, 0, 1, pixel, 0)
print(window.GetClassName(), pixel.GetValue(0), pixel.GetValue(1))
"""


class RenderUnavailable(RuntimeError):
    """No offscreen OpenGL (neither EGL nor OSMesa) works on this machine: 3D pictures cannot be drawn."""


def _probe(window_class: str, timeout_s: float = 60.0) -> bool:
    """Whether VTK renders a red pixel with ``window_class`` (tried in a subprocess: it may segfault)."""
    env = dict(os.environ, VTK_DEFAULT_OPENGL_WINDOW=window_class)
    try:
        done = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True,
                              timeout=timeout_s)
    except (OSError, subprocess.TimeoutExpired):
        return False
    words = done.stdout.split()
    return done.returncode == 0 and words[:3] == [window_class, "255", "0"]


def offscreen_backend() -> str | None:
    """The offscreen backend VTK renders with here, ``"egl"`` or ``"osmesa"``; ``None`` if neither works.

    Probed once per process (EGL first, then OSMesa), then cached; the choice
    is put into ``VTK_DEFAULT_OPENGL_WINDOW`` and ``ESENSE_OFFSCREEN_BACKEND``
    so that child processes inherit it without probing. Setting
    ``ESENSE_OFFSCREEN_BACKEND`` to ``egl``, ``osmesa`` or ``none`` beforehand
    skips the probe.

    Example
    -------
    >>> offscreen_backend() in ("egl", "osmesa", None)
    True
    """
    if _chosen:
        return _chosen[0]
    preset_choice = os.environ.get(_ENV, "").strip().lower()
    if preset_choice in OFFSCREEN_BACKENDS or preset_choice == "none":
        name = None if preset_choice == "none" else preset_choice
    else:
        name = next((n for n, cls in OFFSCREEN_BACKENDS.items() if _probe(cls)), None)
    if name is not None:
        os.environ["VTK_DEFAULT_OPENGL_WINDOW"] = OFFSCREEN_BACKENDS[name]
    os.environ[_ENV] = name or "none"
    _chosen.append(name)
    return name


def can_render_3d() -> bool:
    """Whether 3D pictures (pyvista, offscreen) can be drawn on this machine (see :func:`offscreen_backend`)."""
    return offscreen_backend() is not None


def require_3d() -> None:
    """Raise :class:`RenderUnavailable`, saying what to install, when no offscreen backend works."""
    if not can_render_3d():
        raise RenderUnavailable(
            "3D pictures cannot be drawn: VTK finds no offscreen OpenGL here (neither EGL nor OSMesa). Install "
            "Mesa's EGL (Debian/Ubuntu: apt install libegl1 libgl1-mesa-dri) or OSMesa (apt install "
            "libosmesa6), or set ESENSE_OFFSCREEN_BACKEND=egl|osmesa to force one.")


def _pyvista():
    require_3d()
    import pyvista

    return pyvista


def electrode_colour(k: int, emitter: int | None = None) -> str:
    """Colour of electrode k (1-based): gold for the emitter, the insulator (0) grey, receivers by number.

    >>> electrode_colour(2, emitter=2) == EMITTER_COLOUR, electrode_colour(0)
    (True, '#9a9a9a')
    """
    if k == 0:
        return INSULATOR_COLOUR
    if emitter is not None and k == emitter:
        return EMITTER_COLOUR
    return ELECTRODE_COLOURS[(k - 1) % len(ELECTRODE_COLOURS)]


def electrode_legend(electrodes, emitter: int | None, roles: bool = True) -> list[tuple[str, str]]:
    """Legend entries ``("electrode k (emitter)", colour)``: the emitter first, the receivers, the insulator.

    ``roles`` False (a scene without a sensor: electrodes on a tank, in the
    water): ``"electrode k"`` in order, no emitter.
    """
    entries = []
    for k in sorted(electrodes, key=lambda k: (roles and k != emitter, k)):
        role = (" (emitter)" if k == emitter else " (receiver)") if roles else ""
        entries.append((f"electrode {k}{role}", electrode_colour(k, emitter)))
    entries.append(("insulator", INSULATOR_COLOUR))
    return entries


def _polydata(mesh: LabelledMesh, mask: np.ndarray):
    pv = _pyvista()
    sub = mesh.select(mask)
    return pv.PolyData(sub.vertices_m, np.c_[np.full(sub.n_triangles, 3), sub.faces].ravel())


def _add_parts(plotter, mesh: LabelledMesh, show_edges: bool, tank_opacity: float, detail: bool,
               emitter: int | None = None):
    """Add the sensor (by electrode), tank and objects of ``mesh`` to a plotter (sub)plot.

    In an overview (``detail`` False) of a scene the small parts are drawn
    without their edges, which would otherwise paint them black.
    """
    names = np.asarray(mesh.region_names)[mesh.region]
    is_tank, is_object, is_body = _parts(names)
    small_edges = show_edges and (detail or not is_tank.any())
    edge_kw = dict(show_edges=small_edges, edge_color="#404040", line_width=0.5)
    shading = dict(specular=0.2, ambient=0.3, diffuse=0.8)
    solid = is_body if detail else ~is_object & (is_body | (mesh.electrode > 0))   # electrodes on the tank: opaque
    for k in np.unique(mesh.electrode[solid]):
        plotter.add_mesh(_polydata(mesh, solid & (mesh.electrode == k)), color=electrode_colour(int(k), emitter),
                         **edge_kw, **shading)
    is_tank = is_tank & (mesh.electrode == 0)
    if is_object.any():
        plotter.add_mesh(_polydata(mesh, is_object), color=OBJECT_COLOUR, **edge_kw, **shading)
    if is_tank.any() and not detail:
        free = names == "free_surface"
        walls = is_tank & ~free
        for sel, colour in ((walls, TANK_COLOUR), (free, FREE_SURFACE_COLOUR)):
            if sel.any():
                plotter.add_mesh(_polydata(mesh, sel), color=colour, opacity=tank_opacity, show_edges=show_edges,
                                 edge_color="#7a9cc6", line_width=0.4, ambient=0.4)


def facing_emitter(mesh: LabelledMesh, emitter: int | None, base=(0.45, -1.0, 0.55)) -> tuple:
    """An oblique view direction from the emitter's end of the sensor (x flipped when the emitter lies at -x)."""
    view = np.asarray(base, dtype=float)
    if emitter is not None and np.any(mesh.electrode == emitter):
        body = mesh.vertices_m[mesh.faces[mesh.electrode > 0]].reshape(-1, 3)
        at = mesh.vertices_m[mesh.faces[mesh.electrode == emitter]].reshape(-1, 3).mean(axis=0)
        if at[0] < 0.5 * (body[:, 0].min() + body[:, 0].max()) - 1e-9:
            view[0] = -view[0]
    return tuple(view)


def _padded_bounds(lo: np.ndarray, hi: np.ndarray, min_fraction: float = 0.3, margin: float = 0.05):
    """Bounds around [lo, hi] with every side at least ``min_fraction`` of the longest (legible axes)."""
    centre, extent = 0.5 * (lo + hi), hi - lo
    extent = np.maximum(extent, min_fraction * extent.max()) * (1 + 2 * margin)
    lo, hi = centre - extent / 2, centre + extent / 2
    return (lo[0], hi[0], lo[1], hi[1], lo[2], hi[2])


def _axes(plotter, font_size: int, bounds):
    plotter.show_bounds(bounds=bounds, xtitle="x (m)", ytitle="y (m)", ztitle="z (m)", font_size=font_size,
                        fmt="%.2f", grid="back", location="outer", ticks="outside", color="#202020",
                        n_xlabels=3, n_ylabels=3, n_zlabels=3, minor_ticks=False, bold=False)


def _add_legend(plotter, entries, scale: float = 1.0):
    """A legend in the upper right corner of the current panel: a coloured square and text per entry."""
    width, height = 0.34 * scale, 0.055 * scale * len(entries)
    legend = plotter.add_legend([[label, colour] for label, colour in entries], bcolor="white", border=False,
                                size=(width, height), face="rectangle")
    legend.SetPosition(1.0 - width - 0.01, 1.0 - height - 0.06)  # pyvista's loc ignores the size


def mesh_plotter(mesh: LabelledMesh, *, title: str | None = None, emitter: int | None = None,
                 window_size: tuple[int, int] = (1600, 1000), show_edges: bool = True, tank_opacity: float = 0.12,
                 close_up: bool | None = None, view_vector=None, off_screen: bool = True):
    """A :class:`pyvista.Plotter` showing a labelled mesh (see :func:`render_mesh` for the parameters)."""
    pv = _pyvista()
    if mesh.n_triangles == 0:
        raise ValueError("render_mesh: the mesh has no triangles")
    electrodes = mesh.electrodes
    if emitter is None and electrodes:
        emitter = max(electrodes)
    if view_vector is None:
        view_vector = facing_emitter(mesh, emitter)
    names = np.asarray(mesh.region_names)[mesh.region]
    is_tank, is_object, is_body = _parts(names)
    has_body = bool(is_body.any())
    if close_up is None:
        close_up = bool(electrodes) and has_body and bool(is_tank.any() or is_object.any())
    font = max(12, int(window_size[1] / 55))
    plotter = pv.Plotter(off_screen=off_screen, window_size=list(window_size), shape=(1, 2) if close_up else (1, 1),
                         border=False)
    plotter.set_background(BACKGROUND)
    panels = [(0, False)] + ([(1, True)] if close_up else [])
    for column, detail in panels:
        plotter.subplot(0, column)
        _add_parts(plotter, mesh, show_edges, tank_opacity, detail, emitter)
        part = mesh.select(is_body) if detail else mesh
        lo, hi = part.vertices_m.min(axis=0), part.vertices_m.max(axis=0)
        if detail:  # the sensor and what is near it
            pad = 0.5 * np.max(hi - lo)
            near = mesh.select(~np.isin(names, list(_TANK_REGIONS))).vertices_m
            near = near[np.all((near > lo - pad) & (near < hi + pad), axis=1)]
            lo, hi = near.min(axis=0), near.max(axis=0)
        bounds = _padded_bounds(lo, hi, margin=0.05 if detail or not close_up else 0.0)
        _axes(plotter, font, bounds)
        plotter.view_vector(view_vector)
        plotter.reset_camera(bounds=bounds)
        plotter.camera.zoom(0.9 if close_up else 1.05)
        heading = "close-up of the sensor" if detail else title
        if heading:
            plotter.add_text(heading, position="upper_left", font_size=font, color="black")
    if electrodes:
        _add_legend(plotter, electrode_legend(electrodes, emitter, roles=has_body), 1.0 if close_up else 0.7)
    return plotter


def render_mesh(mesh: LabelledMesh, png_path: str | Path, *, title: str | None = None, emitter: int | None = None,
                window_size: tuple[int, int] = (1600, 1000), show_edges: bool = True, tank_opacity: float = 0.12,
                close_up: bool | None = None, view_vector=None) -> Path:
    """Write an offscreen picture (PNG) of a labelled mesh (sensor, object, tank or whole scene).

    Parameters
    ----------
    mesh : LabelledMesh
        Faces of regions ``TANK_REGIONS`` are drawn translucent, regions
        ``object_*`` in bronze, everything else by electrode label.
    png_path : path
    title : str, optional
        Heading of the picture.
    emitter : int, optional
        Electrode named "(emitter)" in the legend (default: the last one).
    window_size : (int, int)
        Picture size in pixels.
    show_edges : bool
        Draw the triangle edges (shows the mesh grading).
    tank_opacity : float
        Opacity of the tank walls and free surface.
    close_up : bool, optional
        Add a panel with a close-up of the sensor; default: when the mesh
        holds a tank or objects as well as electrodes.
    view_vector : 3 floats, optional
        Direction from the focal point to the camera; default: obliquely from
        the side of the emitter, so that it is in sight.

    Returns
    -------
    Path of the PNG written.
    """
    png_path = Path(png_path)
    plotter = mesh_plotter(mesh, title=title, emitter=emitter, window_size=window_size, show_edges=show_edges,
                           tank_opacity=tank_opacity, close_up=close_up, view_vector=view_vector)
    png_path.parent.mkdir(parents=True, exist_ok=True)
    plotter.screenshot(str(png_path))
    plotter.close()
    return png_path


def data_plotter(poly, scalars: str | None = None, *, title: str | None = None,
                 window_size: tuple[int, int] = (1600, 1000), off_screen: bool = True, cmap: str = "coolwarm"):
    """A plotter colouring a surface by one of its data arrays (a surface solution, say).

    ``scalars`` names a cell or point array; by default the first one that is
    not a label (``electrode``, ``region``).
    """
    pv = _pyvista()
    arrays = [n for n in list(poly.cell_data.keys()) + list(poly.point_data.keys()) if n not in ("electrode", "region")]
    if scalars is None:
        if not arrays:
            raise ValueError("the surface has no data array to colour by (only labels)")
        scalars = arrays[0]
    elif scalars not in poly.cell_data and scalars not in poly.point_data:
        raise ValueError(f"no data array {scalars!r}; arrays: {', '.join(arrays) or 'none'}")
    font = max(12, int(window_size[1] / 55))
    plotter = pv.Plotter(off_screen=off_screen, window_size=list(window_size))
    plotter.set_background(BACKGROUND)
    plotter.add_mesh(poly, scalars=scalars, cmap=cmap, show_edges=False,
                     scalar_bar_args=dict(title=scalars, color="black", title_font_size=font, label_font_size=font,
                                          vertical=True, position_x=0.86, position_y=0.2, height=0.6, fmt="%.3g"))
    lo, hi = np.asarray(poly.bounds[::2]), np.asarray(poly.bounds[1::2])
    bounds = _padded_bounds(lo, hi)
    _axes(plotter, font, bounds)
    plotter.view_vector((0.45, -1.0, 0.55))
    plotter.reset_camera(bounds=bounds)
    if title:
        plotter.add_text(title, position="upper_left", font_size=font, color="black")
    return plotter


def render_data(poly, png_path: str | Path, scalars: str | None = None, *, title: str | None = None,
                window_size: tuple[int, int] = (1600, 1000)) -> Path:
    """Write a PNG of a surface coloured by a data array (see :func:`data_plotter`)."""
    png_path = Path(png_path)
    plotter = data_plotter(poly, scalars, title=title, window_size=window_size)
    png_path.parent.mkdir(parents=True, exist_ok=True)
    plotter.screenshot(str(png_path))
    plotter.close()
    return png_path
