"""Tank maps: what each receiver reads over the tank, as matplotlib maps with the tank outline.

For a grid sweep (:func:`electrosense.validation.simulation.sweep.store.as_map`), one panel per
receiver shows over (x, y), at one heading, either the resistance U/I (ohm) or
the relative current change against the pose nearest the middle of the tank
(percent, on a colour scale symmetric around 0), with the tank walls drawn,
axes in metres, a colour bar with units and a title per receiver; a PDF is
written beside the PNG. No display and no OpenGL are needed.

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
    from electrosense.validation.simulation.sweep.store import as_map

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
    from matplotlib.patches import Rectangle
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
    width_in = panel_px / DPI
    height_in = width_in * (extent[3] - extent[2]) / max(extent[1] - extent[0], 1e-12) + 0.9
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
        clipped = values[k].max() > image.norm.vmax or values[k].min() < image.norm.vmin
        bar = fig.colorbar(image, ax=ax, label=unit_label.format(k=receiver), location="bottom", shrink=0.9,
                           extend="both" if clipped else "neither")
        bar.locator = MaxNLocator(nbins=4)
        bar.update_ticks()
        if tank:
            ax.add_patch(Rectangle((extent[0], extent[2]), tank[0], tank[1], fill=False, color="black", lw=1.5))
        pad = 0.03 * max(extent[1] - extent[0], extent[3] - extent[2])
        ax.set_xlim(extent[0] - pad, extent[1] + pad)
        ax.set_ylim(extent[2] - pad, extent[3] + pad)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_title(f"receiver {receiver}")
    fig.suptitle(f"{model} {sensor}: {what}, yaw {yaw:.3g} rad, z {z:.3g} m")
    return save(fig, png_path)
