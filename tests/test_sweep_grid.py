"""Pose grids and lines, the store as xarray sees it, netCDF export and the tank-map picture."""
from __future__ import annotations

import json

import numpy as np
import pytest
from test_sweep_runner import WallImageEvaluator

from electrosense.validation.simulation.sweep import (
    GridError,
    SweepStore,
    as_map,
    export_netcdf,
    line_poses,
    open_sweep,
    parse_grid,
    run_sweep,
)
from electrosense.validation.simulation.sweep.store import StoreError


def test_grid_order_is_yaw_then_y_then_x():
    g = parse_grid("-0.2:0.2:5,-0.1:0.1:3,0:3:4", z_m=-0.05)
    assert g.shape == (4, 3, 5)
    p = g.poses.reshape(g.shape + (4,))
    np.testing.assert_allclose(p[0, 0, :, 0], np.linspace(-0.2, 0.2, 5))  # x fastest
    np.testing.assert_allclose(p[0, :, 0, 1], np.linspace(-0.1, 0.1, 3))
    np.testing.assert_allclose(p[:, 0, 0, 3], np.linspace(0, 3, 4))  # yaw slowest
    assert np.all(p[..., 2] == -0.05)
    assert parse_grid("0:1:2,0:1:2", yaw_rad=0.7).poses[:, 3].tolist() == [0.7] * 4


def test_grid_round_trips_through_its_attribute_form():
    g = parse_grid("-0.3:0.3:7,-0.2:0.2:5,0:1.5:2", z_m=0.1)
    back = type(g).from_dict(json.dumps(g.to_dict()))
    np.testing.assert_array_equal(back.poses, g.poses)


@pytest.mark.parametrize("text, message", [
    ("0:1:3", "expected X0:X1:NX,Y0:Y1:NY"),
    ("0:1,0:1:3", "grid x axis '0:1': expected START:STOP:COUNT"),
    ("0:1:a,0:1:3", "integer COUNT"),
    ("0:1:0,0:1:3", "positive integer"),
    ("0:1:1,0:1:3", "one value cannot span"),
    ("0:nan:3,0:1:3", "finite"),
])
def test_bad_grids_are_refused_with_the_reason(text, message):
    with pytest.raises(GridError, match=message):
        parse_grid(text)


def test_line_includes_both_ends():
    p = line_poses((-0.4, 0.1), (0.4, -0.1), 161, yaw_rad=0.2, z_m=-0.1)
    assert p.shape == (161, 4)
    np.testing.assert_allclose(p[[0, -1], :2], [[-0.4, 0.1], [0.4, -0.1]])
    np.testing.assert_allclose(np.diff(p[:, 0]), 0.005)
    with pytest.raises(GridError, match="positive number of poses"):
        line_poses((0, 0), (1, 0), 0)


def test_store_reads_back_with_xarray_as_a_tank_map_and_as_netcdf(tmp_path):
    g = parse_grid("-0.3:0.3:6,-0.2:0.2:4,0:1.5:2")
    ev = WallImageEvaluator()
    store = SweepStore.open_or_create(tmp_path / "m.zarr", g.poses, 4, 4, {"model": "stand-in"}, 10,
                                      attrs={"grid": g.to_dict()})
    with pytest.raises(StoreError, match="not computed yet"):
        store.conductance(0.05)
    C = run_sweep(ev, g.poses, store, workers=1, progress=False).conductance
    ds = open_sweep(tmp_path / "m.zarr")
    assert ds.K_S.attrs["units"] == "S" and ds.R_ohm.attrs["units"] == "ohm"
    np.testing.assert_allclose(ds.R_ohm.values, 1.0 / ds.I_A.values)
    np.testing.assert_allclose(ds.I_A.values, C.receiver_currents_A(1.0))
    assert ds.receiver.values.tolist() == [1, 2, 3]
    m = as_map(ds)
    assert dict(m.R_ohm.sizes) == {"yaw_rad": 2, "y_m": 4, "x_m": 6, "receiver": 3}
    # the map's cell (yaw, y, x) is the pose at that yaw, y and x
    cell = m.R_ohm.isel(yaw_rad=1, y_m=2, x_m=5).values
    i = int(np.flatnonzero((ds.x_m.values == m.x_m.values[5]) & (ds.y_m.values == m.y_m.values[2])
                           & (ds.yaw_rad.values == m.yaw_rad.values[1]))[0])
    np.testing.assert_array_equal(cell, ds.R_ohm.values[i])
    nc = export_netcdf(tmp_path / "m.zarr", tmp_path / "m.nc")
    back = open_sweep(nc)
    np.testing.assert_array_equal(back.K_S.values, ds.K_S.values)
    assert back.attrs["fingerprint"] == ds.attrs["fingerprint"]


def test_tank_map_png(tmp_path):
    from electrosense.validation.simulation.sweep.plot import plot_tank_map, tank_map_values

    g = parse_grid("-0.3:0.3:13,-0.3:0.3:13")
    store = SweepStore.open_or_create(tmp_path / "m.zarr", g.poses, 4, 4, {"model": "stand-in"}, 64,
                                      attrs={"grid": g.to_dict(), "tank_m": [1.0, 1.0, 1.0], "sensor_name": "four"})
    run_sweep(WallImageEvaluator(), g.poses, store, workers=1, progress=False)
    change, x, y, yaw, receivers = tank_map_values(store.dataset(), "current_change")
    assert change.shape == (3, 13, 13) and change[:, 6, 6].tolist() == [0.0, 0.0, 0.0]  # mid-tank reference
    # the stand-in's wall is at x = +0.5: currents change most on the side nearest it
    assert np.all(np.abs(change[:, :, -1]).mean(axis=1) > np.abs(change[:, :, 0]).mean(axis=1))
    png = plot_tank_map(store.dataset(), tmp_path / "map.png", "resistance", panel_px=300)
    import pyvista as pv

    image = pv.read(png)
    assert image.dimensions[0] == 900  # three panels of 300 pixels
    pixels = image.point_data[image.array_names[0]]
    assert len(np.unique(pixels.reshape(len(pixels), -1), axis=0)) > 50  # a coloured map, not a blank canvas


def test_a_grid_too_large_for_memory_is_refused_before_allocating():
    import time

    from electrosense.validation.simulation.sweep.grid import GridError, parse_grid

    t0 = time.perf_counter()
    with pytest.raises(GridError, match=r"--grid gives 900,000,000 poses"):
        parse_grid("-0.3:0.3:30000,-0.3:0.3:30000")
    with pytest.raises(GridError, match="--steps"):
        line_poses((0, 0), (1, 0), 10**9)
    assert time.perf_counter() - t0 < 1.0  # nothing was built
