"""Tank maps: what each receiver reads over the tank, as matplotlib maps with the tank outline.

For a grid sweep (:func:`electrosense.validation.simulation.sweep.store.as_map`), one panel per
receiver shows over (x, y), at one heading, either the resistance U/I (ohm) or
the relative current change against the pose nearest the middle of the tank
(percent, on a colour scale symmetric around 0), with the tank walls (a box
or a cylinder) and the fixed objects' sections at the grid's depth drawn,
axes in metres, a colour bar with units and a title per receiver; a PDF is
written beside the PNG. Poses the model did not reach (``esense sweep
--skip-blocked``) are left blank. No display and no OpenGL are needed.

Example
-------
>>> from electrosense.validation.simulation.sweep.store import open_sweep
>>> from electrosense.validation.simulation.sweep.plot import plot_tank_map
>>> plot_tank_map(open_sweep("tank_map.zarr"), "tank_map.png")  # doctest: +SKIP
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

__all__ = ["QUANTITIES", "tank_map_values", "object_sections", "plot_tank_map"]

#: quantity name -> (label for the colour bar, title word)
QUANTITIES = {
    "resistance": ("R{k} (ohm)", "resistance U/I"),
    "current_change": ("dI{k}/I{k},mid (%)", "current change vs mid-tank"),
}


def tank_map_values(ds, quantity: str = "resistance", yaw_index: int = 0):
    """The map (n_receiver, n_y, n_x) of ``quantity`` at heading ``yaw_index``, with its x and y (m).

    ``"current_change"`` is ``100 (I - I_mid) / I_mid`` with ``I_mid`` the
    current at the reached grid position nearest the middle of the tank (x = y = 0). Poses the model did not
    reach are NaN.
    """
    from electrosense.validation.simulation.sweep.store import as_map

    if quantity not in QUANTITIES:
        raise ValueError(f"quantity {quantity!r}: expected one of {', '.join(QUANTITIES)}")
    m = as_map(ds)
    if not 0 <= yaw_index < m.sizes["yaw_rad"]:
        raise ValueError(f"yaw_index {yaw_index} is outside the grid's {m.sizes['yaw_rad']} headings")
    if not np.asarray(m.computed.values).all():
        raise ValueError("the sweep is not complete (some poses have no result yet): finish it before plotting")
    x, y = m.x_m.values, m.y_m.values
    I = m.I_A.isel(yaw_rad=yaw_index).transpose("receiver", "y_m", "x_m").values
    reached = np.isfinite(I).all(axis=0)
    if not reached.any():
        raise ValueError(f"the model reached no pose at heading {yaw_index}: nothing to plot")
    if quantity == "resistance":
        values = m.R_ohm.isel(yaw_rad=yaw_index).transpose("receiver", "y_m", "x_m").values
    else:
        distance = np.where(reached, np.hypot(*np.meshgrid(x, y)), np.inf)
        i_mid, j_mid = np.unravel_index(np.argmin(distance), distance.shape)
        values = 100.0 * (I / I[:, i_mid:i_mid + 1, j_mid:j_mid + 1] - 1.0)
    return values, x, y, float(m.yaw_rad.values[yaw_index]), m.receiver.values


def object_sections(objects_attr, extent, z_m: float, n: int = 400):
    """The fixed objects (a sweep's ``objects`` attribute) on a raster over ``extent`` (x0, x1, y0, y1) at depth
    ``z_m``: ``(x, y, inside)`` for a contour at 0.5, or ``None`` where no object crosses that plane.

    >>> from electrosense.validation.bench.log.header import objects_meta
    >>> from electrosense.meshes.objects import Sphere
    >>> x, y, inside = object_sections(objects_meta([Sphere((0.1, 0.0, 0.0), radius_m=0.02)]), (-0.5, 0.5, -0.5, 0.5), 0.0)
    >>> float(inside.mean()) > 0
    True
    """
    from electrosense.meshes.scene_mesh import distance_to_object_m
    from electrosense.validation.bench.log.header import logged_objects

    if isinstance(objects_attr, str):
        objects_attr = json.loads(objects_attr)
    if not objects_attr:
        return None
    objects = logged_objects({"objects": objects_attr})
    x = np.linspace(extent[0], extent[1], n)
    y = np.linspace(extent[2], extent[3], n)
    X, Y = np.meshgrid(x, y)
    pts = np.stack([X, Y, np.full_like(X, z_m)], axis=-1)
    inside = np.zeros(X.shape)
    for obj in objects:
        inside = np.maximum(inside, (distance_to_object_m(obj, pts) <= 0).astype(float))
    return (x, y, inside) if inside.any() else None


def plot_tank_map(ds, png_path, quantity: str = "resistance", yaw_index: int = 0, panel_px: int = 640,
                  floor_percent: float = 0.01) -> Path:
    """Write the tank map of every receiver as one PNG (panels side by side) and a PDF beside it.

    Parameters
    ----------
    ds : xarray.Dataset
        A grid sweep (:func:`electrosense.validation.simulation.sweep.store.open_sweep`).
    png_path : str or Path
    quantity : {"resistance", "current_change"}
    yaw_index : int
        Which heading of the grid to show.
    panel_px : int
        Width of one panel in pixels of the PNG.
    floor_percent : float
        For ``current_change``: the colour scale, symmetric around 0, spans at
        least +-this (%), so that round-off over an empty tank is not shown as
        structure.
    """
    from matplotlib.patches import Circle, Rectangle
    from matplotlib.ticker import MaxNLocator

    from electrosense.validation.report.style import DPI, new_figure, save, symmetric_limit

    values, x, y, yaw, receivers = tank_map_values(ds, quantity, yaw_index)
    z = float(json.loads(ds.attrs["grid"])["z_m"]) if isinstance(ds.attrs.get("grid"), str) else 0.0
    tank = json.loads(ds.attrs["tank_m"]) if isinstance(ds.attrs.get("tank_m"), str) else ds.attrs.get("tank_m")
    unit_label, what = QUANTITIES[quantity]
    model = str(ds.attrs.get("model", "model")).upper()
    sensor = ds.attrs.get("sensor_name", "")
    if tank:
        extent = (-tank[0] / 2, tank[0] / 2, -tank[1] / 2, tank[1] / 2)
    else:
        extent = (float(x.min()), float(x.max()), float(y.min()), float(y.max()))
    cylinder = ds.attrs.get("tank_cylinder")
    cylinder = json.loads(cylinder) if isinstance(cylinder, str) else cylinder
    radius_m = float(cylinder["radius_m"]) if cylinder else None
    sections = object_sections(ds.attrs.get("objects"), extent, z)
    width_in = panel_px / DPI
    # the panel at the tank's aspect, and 1.3 in for the colour bar, the panel's title and the figure's
    height_in = width_in * (extent[3] - extent[2]) / max(extent[1] - extent[0], 1e-12) + 1.3
    fig, axes = new_figure(1, len(receivers), (width_in, height_in))
    for k, receiver in enumerate(receivers):
        ax = axes[0, k]
        ax.grid(False)
        if quantity == "current_change":
            top = symmetric_limit(values[k], floor=floor_percent)
            image = ax.pcolormesh(x, y, values[k], shading="nearest", cmap="RdBu_r", vmin=-top, vmax=top,
                                  rasterized=True)
        else:
            image = ax.pcolormesh(x, y, values[k], shading="nearest", cmap="viridis", rasterized=True)
        clipped = np.nanmax(values[k]) > image.norm.vmax or np.nanmin(values[k]) < image.norm.vmin
        bar = fig.colorbar(image, ax=ax, label=unit_label.format(k=receiver), location="bottom", shrink=0.9,
                           extend="both" if clipped else "neither")
        bar.locator = MaxNLocator(nbins=4)
        bar.update_ticks()
        if radius_m is not None:
            ax.add_patch(Circle((0.0, 0.0), radius_m, fill=False, color="black", lw=1.5))
        elif tank:
            ax.add_patch(Rectangle((extent[0], extent[2]), tank[0], tank[1], fill=False, color="black", lw=1.5))
        if sections is not None:
            ax.contour(*sections, levels=[0.5], colors="black", linewidths=1.0)
        pad = 0.03 * max(extent[1] - extent[0], extent[3] - extent[2])
        ax.set_xlim(extent[0] - pad, extent[1] + pad)
        ax.set_ylim(extent[2] - pad, extent[3] + pad)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_title(f"receiver {receiver}")
    blank = ", blank: not reached by the model" if not np.isfinite(values).all() else ""
    fig.suptitle(f"{model} {sensor}: {what}, yaw {yaw:.3g} rad, z {z:.3g} m{blank}")
    return save(fig, png_path)
