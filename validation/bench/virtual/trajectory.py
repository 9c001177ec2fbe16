"""Trajectories of the bench's cartesian robot: wall to wall, lines, grids, several passes.

A path is given as text on the command line:

``wall-to-wall[:N]``
    Straight line along x at y = 0, z = 0, yaw 0, from x = -(Lx/2 - 0.13 m) to
    +(Lx/2 - 0.13 m), ``N`` poses (default 161). For the 1 m tank: -0.37 to
    0.37 m. The paper's near-wall data reach 0.38 m (its figure axes span
    -0.4 to 0.4 m, where the 20 cm sensor's tip would touch the wall); 0.37 m
    keeps the tail sphere of the angels-4 PSM (23.4 cm between the outer
    sphere centres in the paper's fit) inside the water, so that every model
    can be run on the pass.
``line:X0,Y0,Z0,YAW0:X1,Y1,Z1,YAW1:N``
    ``N`` poses evenly spaced from the first pose to the second.
``grid:X0,X1,NX:Y0,Y1,NY[:Z[:YAW]]``
    A raster in the plane z = Z, row by row in alternate directions (serpentine).

Several passes repeat the path, every other pass backwards (the robot goes
back and forth), numbered 0, 1, ... in the ``pass`` column.

Example
-------
>>> from electrosense.validation.bench.virtual.trajectory import parse_path
>>> poses = parse_path("wall-to-wall", tank_size_m=(1.0, 1.0, 1.0))
>>> poses.shape, float(poses[0, 0]), float(poses[-1, 0])
((161, 4), -0.37, 0.37)
"""
from __future__ import annotations

import numpy as np

__all__ = ["wall_to_wall", "line", "grid", "parse_path", "repeat_passes", "WALL_CLEARANCE_M"]

#: Distance kept between the sensor centre and a wall on a wall-to-wall pass:
#: the 20 cm sensor's tip stays 3 cm from the wall, the angels-4 PSM's spheres inside the water.
WALL_CLEARANCE_M = 0.13


def line(start, stop, n: int) -> np.ndarray:
    """(n, 4) poses evenly spaced from ``start`` to ``stop`` (x, y, z, yaw)."""
    if n < 1:
        raise ValueError(f"a line needs at least 1 pose, got {n}")
    s = np.linspace(0.0, 1.0, n)[:, None]
    return (1 - s) * np.asarray(start, dtype=float) + s * np.asarray(stop, dtype=float)


def wall_to_wall(tank_size_m=(1.0, 1.0, 1.0), n: int = 161, clearance_m: float = WALL_CLEARANCE_M) -> np.ndarray:
    """(n, 4): along x at y = z = yaw = 0, from wall to wall, ``clearance_m`` from each."""
    half = 0.5 * float(tank_size_m[0]) - clearance_m
    if half <= 0:
        raise ValueError(f"tank of length {tank_size_m[0]} m is too short for a wall-to-wall pass")
    return line((-half, 0.0, 0.0, 0.0), (half, 0.0, 0.0, 0.0), n)


def grid(x_range, y_range, z_m: float = 0.0, yaw_rad: float = 0.0) -> np.ndarray:
    """Serpentine raster: ``x_range = (x0, x1, nx)``, ``y_range = (y0, y1, ny)``; (nx*ny, 4)."""
    x = np.linspace(x_range[0], x_range[1], int(x_range[2]))
    y = np.linspace(y_range[0], y_range[1], int(y_range[2]))
    rows = [np.stack([x if j % 2 == 0 else x[::-1], np.full_like(x, yj)], axis=1) for j, yj in enumerate(y)]
    xy = np.concatenate(rows)
    return np.column_stack([xy, np.full(len(xy), z_m), np.full(len(xy), yaw_rad)])


def _numbers(text: str, count: int, what: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise ValueError(f"path: {what} {text!r} must be numbers") from None
    if len(values) != count:
        raise ValueError(f"path: {what} {text!r} needs {count} numbers, got {len(values)}")
    return values


def parse_path(spec: str, tank_size_m=(1.0, 1.0, 1.0)) -> np.ndarray:
    """The poses (P, 4) of a path given as text (see the module docstring)."""
    kind, _, rest = spec.partition(":")
    parts = rest.split(":") if rest else []
    try:
        if kind == "wall-to-wall":
            if tank_size_m is None:
                raise ValueError("path wall-to-wall needs a tank")
            return wall_to_wall(tank_size_m, int(parts[0]) if parts else 161)
        if kind == "line":
            if len(parts) != 3:
                raise ValueError("path line:X0,Y0,Z0,YAW0:X1,Y1,Z1,YAW1:N")
            return line(_numbers(parts[0], 4, "start pose"), _numbers(parts[1], 4, "end pose"), int(parts[2]))
        if kind == "grid":
            if len(parts) < 2:
                raise ValueError("path grid:X0,X1,NX:Y0,Y1,NY[:Z[:YAW]]")
            z = float(parts[2]) if len(parts) > 2 else 0.0
            yaw = float(parts[3]) if len(parts) > 3 else 0.0
            return grid(_numbers(parts[0], 3, "x range"), _numbers(parts[1], 3, "y range"), z, yaw)
    except ValueError as exc:
        raise ValueError(f"path {spec!r}: {exc}") from None
    raise ValueError(f"path {spec!r}: unknown kind {kind!r} (wall-to-wall, line, grid)")


def repeat_passes(poses: np.ndarray, n_passes: int = 1, back_and_forth: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """``n_passes`` repetitions of a path: (poses (n*P, 4), pass numbers (n*P,))."""
    if n_passes < 1:
        raise ValueError(f"passes must be >= 1, got {n_passes}")
    runs = [poses[::-1] if back_and_forth and k % 2 else poses for k in range(n_passes)]
    return np.concatenate(runs), np.repeat(np.arange(n_passes), len(poses))
