"""Tank maps: what each receiver reads over the tank, as pyvista images with the tank outline.

For a grid sweep (:func:`validation.sweep.store.as_map`), one panel per
receiver shows over (x, y), at one heading, either the resistance U/I (ohm) or
the relative current change against the pose nearest the middle of the tank
(percent), with the tank walls drawn, axes in metres, a colour bar with units
and a title per receiver. Rendering is offscreen (no display needed).

Example
-------
>>> from validation.sweep.store import open_sweep
>>> from validation.sweep.plot import plot_tank_map
>>> plot_tank_map(open_sweep("tank_map.zarr"), "tank_map.png")  # doctest: +SKIP
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

__all__ = ["QUANTITIES", "tank_map_values", "plot_tank_map"]

#: quantity name -> (label for the colour bar, title word)
QUANTITIES = {
    "resistance": ("R{k} (ohm)", "resistance U/I"),
    "current_change": ("dI{k}/I{k},mid (%)", "current change vs mid-tank"),
}


def tank_map_values(ds, quantity: str = "resistance", yaw_index: int = 0):
    """The map (n_receiver, n_y, n_x) of ``quantity`` at heading ``yaw_index``, with its x and y (m).

    ``"current_change"`` is ``100 (I - I_mid) / I_mid`` with ``I_mid`` the
    current at the grid position nearest the middle of the tank (x = y = 0).
    """
    from .store import as_map

    if quantity not in QUANTITIES:
        raise ValueError(f"quantity {quantity!r}: expected one of {', '.join(QUANTITIES)}")
    m = as_map(ds)
    if not 0 <= yaw_index < m.sizes["yaw_rad"]:
        raise ValueError(f"yaw_index {yaw_index} is outside the grid's {m.sizes['yaw_rad']} headings")
    x, y = m.x_m.values, m.y_m.values
    if quantity == "resistance":
        values = m.R_ohm.isel(yaw_rad=yaw_index).transpose("receiver", "y_m", "x_m").values
    else:
        I = m.I_A.isel(yaw_rad=yaw_index).transpose("receiver", "y_m", "x_m").values
        i_mid, j_mid = int(np.argmin(np.abs(y))), int(np.argmin(np.abs(x)))
        values = 100.0 * (I / I[:, i_mid:i_mid + 1, j_mid:j_mid + 1] - 1.0)
    if not np.all(np.isfinite(values)):
        raise ValueError("the sweep is not complete (some poses have no result yet): finish it before plotting")
    return values, x, y, float(m.yaw_rad.values[yaw_index]), m.receiver.values


def _tank_outline(tank_m, z):
    import pyvista as pv

    lx, ly = tank_m[0] / 2, tank_m[1] / 2
    corners = np.array([[-lx, -ly, z], [lx, -ly, z], [lx, ly, z], [-lx, ly, z]])
    return pv.MultipleLines(np.vstack([corners, corners[:1]]))


def plot_tank_map(ds, png_path, quantity: str = "resistance", yaw_index: int = 0, panel_px: int = 640) -> Path:
    """Write the tank map of every receiver as one PNG (panels side by side).

    Parameters
    ----------
    ds : xarray.Dataset
        A grid sweep (:func:`validation.sweep.store.open_sweep`).
    png_path : str or Path
    quantity : {"resistance", "current_change"}
    yaw_index : int
        Which heading of the grid to show.
    panel_px : int
        Width and height of one panel in pixels.
    """
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkOSOpenGLRenderWindow")
    import pyvista as pv

    values, x, y, yaw, receivers = tank_map_values(ds, quantity, yaw_index)
    z = float(json.loads(ds.attrs["grid"])["z_m"]) if isinstance(ds.attrs.get("grid"), str) else 0.0
    tank = json.loads(ds.attrs["tank_m"]) if isinstance(ds.attrs.get("tank_m"), str) else ds.attrs.get("tank_m")
    unit_label, what = QUANTITIES[quantity]
    model = str(ds.attrs.get("model", "model")).upper()
    sensor = ds.attrs.get("sensor_name", "")

    plotter = pv.Plotter(off_screen=True, shape=(1, len(receivers)), window_size=(panel_px * len(receivers), panel_px),
                         border=False)
    for k, receiver in enumerate(receivers):
        plotter.subplot(0, k)
        grid = pv.RectilinearGrid(x, y, np.array([z]))
        label = unit_label.format(k=receiver)  # unique per panel: pyvista keys colour bars by title
        grid.point_data[label] = values[k].ravel()  # x fastest, as VTK wants
        plotter.add_mesh(
            grid,
            scalars=label,
            cmap="viridis",
            show_scalar_bar=True,
            scalar_bar_args={"title": label, "vertical": True, "fmt": "%.4g", "title_font_size": 14,
                             "label_font_size": 12, "position_x": 0.80, "position_y": 0.15, "width": 0.08,
                             "height": 0.65, "color": "black"},
        )
        bounds_z = [z, z]
        if tank:
            plotter.add_mesh(_tank_outline(tank, z), color="black", line_width=3)
            bounds = [-tank[0] / 2, tank[0] / 2, -tank[1] / 2, tank[1] / 2] + bounds_z
        else:
            bounds = [x.min(), x.max(), y.min(), y.max()] + bounds_z
        plotter.show_bounds(bounds=bounds, xtitle="x (m)", ytitle="y (m)", show_zaxis=False, show_zlabels=False,
                            location="outer", ticks="outside", font_size=10, color="black", fmt="%.2f")
        plotter.add_text(f"{model} {sensor}, receiver {receiver}\n{what}, yaw {yaw:.3g} rad, z {z:.3g} m",
                         position="upper_edge", font_size=10, color="black")
        plotter.set_background("white")
        plotter.view_xy()
        plotter.camera.zoom(0.8)
        plotter.camera.position = np.add(plotter.camera.position, [0.08 * bounds[1], 0, 0])
        plotter.camera.focal_point = np.add(plotter.camera.focal_point, [0.08 * bounds[1], 0, 0])
    png_path = Path(png_path)
    plotter.screenshot(str(png_path))
    plotter.close()
    return png_path
