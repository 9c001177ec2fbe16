"""Pose sets for sweeps: a straight line of poses, or a grid over the tank.

Command-line forms
------------------
* a line: ``--from X0,Y0 --to X1,Y1 --steps N [--yaw A] [--z Z]``: N poses
  evenly spaced from (X0, Y0) to (X1, Y1), both ends included, heading A (rad);
* a grid: ``--grid X0:X1:NX,Y0:Y1:NY[,YAW0:YAW1:NYAW]``: NX x NY positions
  (ends included) at NYAW headings (default: the single heading ``--yaw``).

Grid poses are ordered yaw slowest, then y, then x fastest (C order of the
array shape (NYAW, NY, NX)), so ``values.reshape(grid.shape)`` is a tank map.

Example
-------
>>> from electrosense.validation.simulation.sweep.grid import parse_grid
>>> g = parse_grid("-0.3:0.3:7,-0.2:0.2:5")
>>> g.shape, g.poses.shape
((1, 5, 7), (35, 4))
"""
from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

__all__ = ["GridError", "Axis", "PoseGrid", "parse_grid", "parse_xy", "line_poses", "MAX_SWEEP_POSES",
           "check_pose_count"]

MAX_SWEEP_POSES = 20_000_000
"""Most poses one sweep takes: their array alone is 0.64 GB, the stored K of a 4-electrode sensor 2.6 GB more."""
_BYTES_PER_POSE = 4 * 8 * 3  # the poses array and the meshgrid temporaries that build it


class GridError(ValueError):
    """A pose line or grid that cannot be built as given."""


def check_pose_count(n_poses: int, option: str) -> None:
    """Refuse, before anything is allocated, a sweep of more than :data:`MAX_SWEEP_POSES` poses.

    >>> check_pose_count(1000, "--grid")
    >>> try:
    ...     check_pose_count(30000 * 30000, "--grid")
    ... except GridError as exc:
    ...     print(str(exc)[:43])
    --grid gives 900,000,000 poses (about 86 GB
    """
    if n_poses > MAX_SWEEP_POSES:
        gb = n_poses * _BYTES_PER_POSE / 1e9
        raise GridError(f"{option} gives {n_poses:,} poses (about {gb:.0f} GB of memory to build them, more to "
                        f"store the results); a sweep takes at most {MAX_SWEEP_POSES:,}: use fewer points, or split "
                        f"the region into several sweeps")


@dataclass(frozen=True)
class Axis:
    """``num`` evenly spaced values from ``start`` to ``stop``, both included."""

    start: float
    stop: float
    num: int

    def __post_init__(self):
        if not (np.isfinite(self.start) and np.isfinite(self.stop)):
            raise GridError(f"axis {self.start}:{self.stop}:{self.num}: the ends must be finite numbers")
        if int(self.num) != self.num or self.num < 1:
            raise GridError(f"axis {self.start}:{self.stop}:{self.num}: the count must be a positive integer")
        if self.num == 1 and self.start != self.stop:
            raise GridError(f"axis {self.start}:{self.stop}:1: one value cannot span two different ends")

    @property
    def values(self) -> np.ndarray:
        return np.linspace(self.start, self.stop, int(self.num))

    @classmethod
    def parse(cls, text: str, what: str) -> "Axis":
        parts = text.split(":")
        if len(parts) != 3:
            raise GridError(f"grid {what} axis {text!r}: expected START:STOP:COUNT")
        try:
            start, stop = float(parts[0]), float(parts[1])
            num = int(parts[2])
        except ValueError:
            raise GridError(f"grid {what} axis {text!r}: expected numbers START:STOP and an integer COUNT") from None
        try:
            return cls(start, stop, num)
        except GridError as exc:
            raise GridError(f"grid {what} axis: {exc}") from None


@dataclass(frozen=True)
class PoseGrid:
    """A grid of poses: x (m) by y (m) by yaw (rad) at height z (m).

    ``shape`` is (n_yaw, n_y, n_x); ``poses`` is (n_yaw * n_y * n_x, 4) in
    that C order (x fastest).
    """

    x: Axis
    y: Axis
    yaw: Axis
    z_m: float = 0.0

    @property
    def shape(self) -> tuple[int, int, int]:
        return (int(self.yaw.num), int(self.y.num), int(self.x.num))

    @property
    def poses(self) -> np.ndarray:
        yaw, y, x = np.meshgrid(self.yaw.values, self.y.values, self.x.values, indexing="ij")
        return np.stack([x.ravel(), y.ravel(), np.full(x.size, float(self.z_m)), yaw.ravel()], axis=1)

    def to_dict(self) -> dict:
        """The grid as plain numbers (for store attributes)."""
        return {
            "x_m": [self.x.start, self.x.stop, int(self.x.num)],
            "y_m": [self.y.start, self.y.stop, int(self.y.num)],
            "yaw_rad": [self.yaw.start, self.yaw.stop, int(self.yaw.num)],
            "z_m": float(self.z_m),
            "order": "yaw slowest, then y, then x fastest",
        }

    @classmethod
    def from_dict(cls, d: dict | str) -> "PoseGrid":
        if isinstance(d, str):
            d = json.loads(d)
        return cls(Axis(*d["x_m"]), Axis(*d["y_m"]), Axis(*d["yaw_rad"]), float(d["z_m"]))


def parse_grid(text: str, yaw_rad: float = 0.0, z_m: float = 0.0) -> PoseGrid:
    """``"X0:X1:NX,Y0:Y1:NY[,YAW0:YAW1:NYAW]"`` as a :class:`PoseGrid` (m, m, rad)."""
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) not in (2, 3):
        raise GridError(f"grid {text!r}: expected X0:X1:NX,Y0:Y1:NY[,YAW0:YAW1:NYAW]")
    x = Axis.parse(parts[0], "x")
    y = Axis.parse(parts[1], "y")
    yaw = Axis.parse(parts[2], "yaw") if len(parts) == 3 else Axis(float(yaw_rad), float(yaw_rad), 1)
    check_pose_count(int(x.num) * int(y.num) * int(yaw.num), "--grid")
    return PoseGrid(x, y, yaw, float(z_m))


def parse_xy(text: str, what: str = "point") -> tuple[float, float]:
    """``"X,Y"`` (m) as two floats."""
    try:
        values = [float(v) for v in str(text).split(",")]
    except ValueError:
        raise GridError(f"{what} {text!r}: expected X,Y as numbers (m)") from None
    if len(values) != 2 or not all(np.isfinite(values)):
        raise GridError(f"{what} {text!r}: expected two finite numbers X,Y (m)")
    return values[0], values[1]


def line_poses(start_xy, stop_xy, steps: int, yaw_rad: float = 0.0, z_m: float = 0.0) -> np.ndarray:
    """``steps`` poses (steps, 4) evenly spaced from ``start_xy`` to ``stop_xy``, both included.

    >>> line_poses((-0.4, 0.0), (0.4, 0.0), 3)[:, 0]
    array([-0.4,  0. ,  0.4])
    """
    if int(steps) != steps or steps < 1:
        raise GridError(f"--steps must be a positive number of poses, got {steps}")
    check_pose_count(int(steps), "--steps")
    if steps == 1 and tuple(start_xy) != tuple(stop_xy):
        raise GridError("--steps 1 gives one pose: --from and --to must then be the same point")
    t = np.linspace(0.0, 1.0, int(steps))[:, None]
    xy = (1 - t) * np.asarray(start_xy, dtype=float) + t * np.asarray(stop_xy, dtype=float)
    return np.column_stack([xy, np.full(len(t), float(z_m)), np.full(len(t), float(yaw_rad))])
