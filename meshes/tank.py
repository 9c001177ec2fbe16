"""The tank: the inner box of a rectangular tank, filled to a water depth.

The water occupies ``|x| <= Lx/2, |y| <= Ly/2, -Lz/2 <= z <= -Lz/2 + depth``
in the tank frame (see :mod:`electrosense.meshes.pose`). Walls, floor and the free surface
are all insulating boundaries for the physics packages. ``None`` in place of
a tank means unbounded water.

Example
-------
>>> from electrosense.meshes.tank import Tank
>>> t = Tank((1.0, 1.0, 1.0), water_depth_m=0.8)
>>> t.free_surface_z_m
0.30000000000000004
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Tank", "TANK_REGIONS"]

#: Names of the tank's boundary regions, in the order used for face labels.
TANK_REGIONS = ("wall_x-", "wall_x+", "wall_y-", "wall_y+", "floor", "free_surface")


@dataclass(frozen=True)
class Tank:
    """Inner size (Lx, Ly, Lz) in metres and water depth (default Lz)."""

    size_m: tuple[float, float, float]
    water_depth_m: float | None = None

    def __post_init__(self):
        size = tuple(float(v) for v in self.size_m)
        if len(size) != 3 or not all(np.isfinite(size)) or min(size) <= 0:
            raise ValueError(f"tank size must be three positive lengths (m), got {self.size_m}")
        object.__setattr__(self, "size_m", size)
        depth = size[2] if self.water_depth_m is None else float(self.water_depth_m)
        if not 0 < depth <= size[2] + 1e-12:
            raise ValueError(f"tank water depth {depth} m must lie in (0, Lz = {size[2]}]")
        object.__setattr__(self, "water_depth_m", depth)

    @property
    def region_names(self) -> tuple[str, ...]:
        """The boundary regions, in the order of :meth:`distance_to_boundary_m`'s columns."""
        return TANK_REGIONS

    @property
    def flat_region_pairs(self) -> tuple[tuple[str, str], ...]:
        """The regions that are planes with all the water on one side (every face of a box), in pairs of
        opposite faces (parallel planes)."""
        return tuple(zip(TANK_REGIONS[::2], TANK_REGIONS[1::2]))

    @property
    def floor_z_m(self) -> float:
        return -0.5 * self.size_m[2]

    @property
    def free_surface_z_m(self) -> float:
        return self.floor_z_m + self.water_depth_m

    @property
    def water_bounds_m(self) -> np.ndarray:
        """(2, 3): lower and upper corners of the water volume."""
        lx, ly, _ = self.size_m
        return np.array([[-lx / 2, -ly / 2, self.floor_z_m], [lx / 2, ly / 2, self.free_surface_z_m]])

    def distance_to_boundary_m(self, points_m: np.ndarray) -> np.ndarray:
        """Distance (..., 6) of each point to the six planes, ordered as ``TANK_REGIONS``.

        Negative values mean the point is outside the water across that plane.
        """
        p = np.asarray(points_m, dtype=float)
        lo, hi = self.water_bounds_m
        return np.stack(
            [p[..., 0] - lo[0], hi[0] - p[..., 0], p[..., 1] - lo[1], hi[1] - p[..., 1], p[..., 2] - lo[2], hi[2] - p[..., 2]],
            axis=-1,
        )

    def contains(self, points_m: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
        """True where the points lie in the water at least ``margin_m`` from every boundary."""
        return np.all(self.distance_to_boundary_m(points_m) >= margin_m, axis=-1)
