"""The potential on the sensor's horizontal mid-plane, from a BEM solution, for pictures.

The plane is z = z_pose (the plane of the sensor's axis), centred on the
sensor, in tank-frame axes. Points inside the sensor body are left NaN (they
are not in the water); the emitter is at ``U_V`` and the receivers at 0 V, as
on the bench.

Example
-------
>>> from electrosense.meshes.sensor import preset
>>> from electrosense.meshes.pose import Pose
>>> plane = mid_plane_potential(preset("angels-2"), Pose(), None, 0.0354, n=21)   # doctest: +SKIP
>>> plane.potential_V.shape                                                   # doctest: +SKIP
(15, 21)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PlanePotential", "mid_plane_potential", "sensor_outline_xy", "electrode_segments_xy", "inside_sensor",
           "electrode_seeds_xy", "tank_walls_xy"]


@dataclass
class PlanePotential:
    """Potential (V) on a grid ``x_m`` (nx,) by ``y_m`` (ny,): ``potential_V`` (ny, nx), NaN inside the sensor."""

    x_m: np.ndarray
    y_m: np.ndarray
    potential_V: np.ndarray
    seconds: float = 0.0


def inside_sensor(sensor, points_sensor_m: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
    """True for points (..., 3, sensor frame) inside the capsule (cylinder with hemispherical ends), plus a margin."""
    p = np.asarray(points_sensor_m, dtype=float)
    half = 0.5 * sensor.length_m - sensor.radius_m
    x = np.clip(p[..., 0], -half, half)
    d = np.sqrt((p[..., 0] - x) ** 2 + p[..., 1] ** 2 + p[..., 2] ** 2)
    return d <= sensor.radius_m + margin_m


def sensor_outline_xy(sensor, pose, n: int = 65) -> np.ndarray:
    """Closed outline (k, 2) of the sensor's cut by its mid-plane, in the tank frame (m)."""
    r, half = sensor.radius_m, 0.5 * sensor.length_m - sensor.radius_m
    t = np.linspace(-np.pi / 2, np.pi / 2, n)
    head = np.column_stack([half + r * np.cos(t), r * np.sin(t)])
    tail = np.column_stack([-half - r * np.cos(t), -r * np.sin(t)])
    pts = np.vstack([head, tail])
    return pose.to_tank(np.column_stack([pts, np.zeros(len(pts))]))[:, :2]


def electrode_segments_xy(sensor, pose, n: int = 24) -> list:
    """Per electrode, its trace on the mid-plane outline (both sides) as one polyline (k, 2), with a label."""
    r, half_len = sensor.radius_m, 0.5 * sensor.length_m
    out = []
    for k, e in enumerate(sensor.electrodes, start=1):
        x = np.linspace(e.x_min_m, e.x_max_m, n)
        cap_start = half_len - r
        # on a cap the outline follows the hemisphere
        y = np.where(np.abs(x) > cap_start, np.sqrt(np.clip(r**2 - (np.abs(x) - cap_start) ** 2, 0, None)), r)
        upper = np.column_stack([x, y, np.zeros(n)])
        lower = np.column_stack([x[::-1], -y[::-1], np.zeros(n)])
        nan = np.full((1, 3), np.nan)
        pts = np.vstack([upper, nan, lower]) if e.kind == "ring" else np.vstack([upper, lower])
        tank = pose.to_tank(np.nan_to_num(pts, nan=0.0))
        tank[np.isnan(pts[:, 0])] = np.nan
        role = "emitter" if k == sensor.emitter else "receiver"
        out.append((tank[:, :2], f"electrode {k} ({role})"))
    return out


def mid_plane_potential(
    sensor,
    pose,
    tank,
    sigma_S_per_m: float,
    U_V: float = 1.0,
    half_width_m: float | None = None,
    n: int = 81,
    edge_length_m: float | None = None,
    objects=(),
) -> PlanePotential:
    """Solve the BEM at ``pose`` and sample the potential on the mid-plane around the sensor.

    Parameters
    ----------
    sensor, pose, tank : the scene (``tank`` None for unbounded water)
    sigma_S_per_m : float
    U_V : float
        Emitter potential above the receivers.
    half_width_m : float, optional
        Half width of the picture along x (default: 0.75 sensor lengths); the
        height is 2/3 of the width. Clipped to the tank.
    n : int
        Grid points along x.
    edge_length_m : float, optional
        BEM mesh edge length.
    """
    import time

    from electrosense.bem.solve import solve_scene
    from electrosense.meshes.scene import Scene

    t0 = time.perf_counter()
    w = 0.75 * sensor.length_m if half_width_m is None else float(half_width_m)
    h = 2.0 * w / 3.0
    cx, cy, cz = pose.x_m, pose.y_m, pose.z_m
    x = np.linspace(cx - w, cx + w, n)
    y = np.linspace(cy - h, cy + h, max(int(round(n * h / w)), 3))
    if tank is not None:
        lo, hi = tank.water_bounds_m
        x = x[(x > lo[0]) & (x < hi[0])]
        y = y[(y > lo[1]) & (y < hi[1])]
    X, Y = np.meshgrid(x, y)
    pts = np.stack([X, Y, np.full_like(X, cz)], axis=-1)
    solution = solve_scene(Scene(sensor, pose, tank, tuple(objects)), sigma_S_per_m, edge_length_m=edge_length_m)
    V = np.zeros(sensor.n_electrodes)
    V[sensor.emitter - 1] = U_V
    inside = inside_sensor(sensor, pose.to_sensor(pts), margin_m=0.002)
    phi = np.full(X.shape, np.nan)
    phi[~inside] = solution.potential_at(pts[~inside], V)
    return PlanePotential(x, y, phi, time.perf_counter() - t0)


def electrode_seeds_xy(sensor, pose, electrode: int, offset_m: float, n: int = 24) -> np.ndarray:
    """Start points (n, 2) of current lines: the electrode's trace on the mid-plane pushed ``offset_m`` into the water."""
    e = sensor.electrodes[electrode - 1]
    r, half = sensor.radius_m, 0.5 * sensor.length_m - sensor.radius_m
    if e.kind == "cap":
        sign = 1.0 if e.x_max_m > 0 else -1.0
        t = np.linspace(-np.pi / 2 * 0.95, np.pi / 2 * 0.95, n)
        pts = np.column_stack([sign * (half + (r + offset_m) * np.cos(t)), (r + offset_m) * np.sin(t)])
    else:
        x = np.linspace(e.x_min_m, e.x_max_m, max(n // 2, 2))
        pts = np.vstack([np.column_stack([x, np.full_like(x, r + offset_m)]),
                         np.column_stack([x, np.full_like(x, -r - offset_m)])])
    return pose.to_tank(np.column_stack([pts, np.zeros(len(pts))]))[:, :2]


def tank_walls_xy(tank, x_range, y_range, tolerance_m: float = 0.0) -> list:
    """The tank's vertical walls within ``tolerance_m`` of the picture, as (2, 2) segments in the plane."""
    if tank is None:
        return []
    (x0, y0, _), (x1, y1, _) = tank.water_bounds_m
    tol = tolerance_m + 1e-9
    out = []
    for x in (x0, x1):
        if x_range[0] - tol <= x <= x_range[1] + tol:
            out.append(np.array([[x, max(y0, y_range[0])], [x, min(y1, y_range[1])]]))
    for y in (y0, y1):
        if y_range[0] - tol <= y <= y_range[1] + tol:
            out.append(np.array([[max(x0, x_range[0]), y], [min(x1, x_range[1]), y]]))
    return out
