"""A cylindrical tank: radius, height and water depth, axis vertical; optionally tapered (a frustum).

Moulded tanks and pails taper: narrower at the floor than at the top. With
``floor_radius_m`` the wall is a frustum, its radius growing linearly from
``floor_radius_m`` at the floor to ``radius_m`` at the top of the tank
(``z = +height/2``); without it the wall is a straight cylinder.

Tank frame: the axis is the z axis, the origin at mid-height of the tank's
inner volume (as for the box :class:`electrosense.meshes.tank.Tank`), floor at
``z = -height/2``, free surface at ``-height/2 + water_depth``. Walls, floor
and free surface are insulating unless a scene puts electrodes on them
(:mod:`electrosense.meshes.surface_electrodes`).

Example
-------
>>> from electrosense.meshes.cylinder_tank import CylinderTank
>>> t = CylinderTank(radius_m=0.15, height_m=0.3, water_depth_m=0.3)
>>> t.floor_z_m, t.free_surface_z_m, t.region_names
(-0.15, 0.15, ('wall', 'floor', 'free_surface'))
>>> pail = CylinderTank(radius_m=0.15, height_m=0.3, floor_radius_m=0.12)
>>> round(float(pail.radius_at(-0.05)), 4), round(pail.wall_slope, 3)
(0.13, 0.1)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CylinderTank", "CYLINDER_TANK_REGIONS"]

#: names of the cylindrical tank's boundary regions, in the order of the face labels
CYLINDER_TANK_REGIONS = ("wall", "floor", "free_surface")


#: a point this close to a boundary, relative to the tank's size, is on it
ON_BOUNDARY_REL_TOL = 1e-6


@dataclass(frozen=True)
class CylinderTank:
    """Inner radius at the top and height (m) of a vertical tank, its water depth (default: full), radius at the floor.

    ``floor_radius_m`` (default: ``radius_m``, a straight wall) makes the wall
    a frustum between the floor's radius and the top's.
    """

    radius_m: float
    height_m: float
    water_depth_m: float | None = None
    floor_radius_m: float | None = None

    def __post_init__(self):
        r, h = float(self.radius_m), float(self.height_m)
        if not (np.isfinite(r) and np.isfinite(h) and r > 0 and h > 0):
            raise ValueError(f"cylindrical tank: radius and height must be positive (m), got {self.radius_m}, "
                             f"{self.height_m}")
        object.__setattr__(self, "radius_m", r)
        object.__setattr__(self, "height_m", h)
        depth = h if self.water_depth_m is None else float(self.water_depth_m)
        if not 0 < depth <= h + 1e-12:
            raise ValueError(f"cylindrical tank: water depth {depth} m must lie in (0, height = {h}]")
        object.__setattr__(self, "water_depth_m", depth)
        rf = r if self.floor_radius_m is None else float(self.floor_radius_m)
        if not (np.isfinite(rf) and rf > 0):
            raise ValueError(f"cylindrical tank: floor_radius_m must be positive (m), got {self.floor_radius_m}")
        object.__setattr__(self, "floor_radius_m", rf)

    @property
    def wall_slope(self) -> float:
        """dr/dz of the wall (0: straight; > 0: wider at the top)."""
        return (self.radius_m - self.floor_radius_m) / self.height_m

    def radius_at(self, z_m):
        """Inner radius (m) of the wall at heights ``z_m`` (tank frame)."""
        return self.floor_radius_m + self.wall_slope * (np.asarray(z_m, dtype=float) - self.floor_z_m)

    @property
    def region_names(self) -> tuple[str, ...]:
        return CYLINDER_TANK_REGIONS

    @property
    def flat_region_pairs(self) -> tuple[tuple[str, str], ...]:
        """The regions that are planes with all the water on one side (the floor and the free surface), in
        pairs of opposite faces (parallel planes)."""
        return (CYLINDER_TANK_REGIONS[1:],)

    @property
    def floor_z_m(self) -> float:
        return -0.5 * self.height_m

    @property
    def free_surface_z_m(self) -> float:
        return self.floor_z_m + self.water_depth_m

    @property
    def water_bounds_m(self) -> np.ndarray:
        """(2, 3): lower and upper corners of the water's bounding box."""
        r = max(self.floor_radius_m, float(self.radius_at(self.free_surface_z_m)))
        return np.array([[-r, -r, self.floor_z_m], [r, r, self.free_surface_z_m]])

    def distance_to_boundary_m(self, points_m: np.ndarray) -> np.ndarray:
        """Distance (..., 3) of each point to the wall, floor and free surface (negative: outside)."""
        p = np.asarray(points_m, dtype=float)
        wall = (self.radius_at(p[..., 2]) - np.hypot(p[..., 0], p[..., 1])) / np.hypot(1.0, self.wall_slope)
        return np.stack([wall, p[..., 2] - self.floor_z_m,
                         self.free_surface_z_m - p[..., 2]], axis=-1)

    @property
    def boundary_tolerance_m(self) -> float:
        """A point this close to a boundary is on it (a millionth of the tank's size: a scene file's rounded
        coordinates land on the wall)."""
        return ON_BOUNDARY_REL_TOL * max(self.radius_m, self.height_m)

    def on_wall(self, point_m) -> bool:
        """Whether a point lies on the wall (within :attr:`boundary_tolerance_m`).

        >>> t = CylinderTank(0.15, 0.3)
        >>> t.on_wall((0.138582, 0.057403, 0.0)), t.on_wall((0.14, 0.0, 0.0))     # 6 decimals of a point at 22.5 deg
        (True, False)
        """
        return bool(abs(self.distance_to_boundary_m(np.asarray(point_m, float))[0]) <= self.boundary_tolerance_m)

    def contains(self, points_m: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
        """True where the points lie in the water at least ``margin_m`` from every boundary."""
        return np.all(self.distance_to_boundary_m(points_m) >= margin_m, axis=-1)
