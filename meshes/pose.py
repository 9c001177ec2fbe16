"""Sensor poses in the tank frame and the rigid transforms they stand for.

Tank frame (bench-log spec): origin at the centre of the tank's inner box,
z up; walls at x = +-Lx/2, y = +-Ly/2, floor at z = -Lz/2. A pose is the
position of the sensor centre (x, y, z, metres) and its heading ``yaw``
(radians, from +x towards +y). At yaw 0 the head (electrode 1) points to +x
and the tail (the emitter) to -x.

Example
-------
>>> import numpy as np
>>> from electrosense.meshes.pose import Pose
>>> p = Pose(0.1, 0.0, 0.0, np.pi / 2)
>>> np.round(p.to_tank(np.array([[0.1, 0.0, 0.0]])), 12)
array([[0.1, 0.1, 0. ]])
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Pose", "rotation_z", "poses_array", "sensor_to_tank"]


def rotation_z(yaw_rad: float | np.ndarray) -> np.ndarray:
    """Rotation matrix (..., 3, 3) about +z by ``yaw_rad``."""
    yaw = np.asarray(yaw_rad, dtype=float)
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.zeros(yaw.shape + (3, 3))
    R[..., 0, 0], R[..., 0, 1] = c, -s
    R[..., 1, 0], R[..., 1, 1] = s, c
    R[..., 2, 2] = 1.0
    return R


@dataclass(frozen=True)
class Pose:
    """Sensor pose in the tank frame: centre (m) and yaw (rad)."""

    x_m: float = 0.0
    y_m: float = 0.0
    z_m: float = 0.0
    yaw_rad: float = 0.0

    @property
    def position_m(self) -> np.ndarray:
        return np.array([self.x_m, self.y_m, self.z_m], dtype=float)

    @property
    def rotation(self) -> np.ndarray:
        return rotation_z(self.yaw_rad)

    def to_tank(self, points_sensor_m: np.ndarray) -> np.ndarray:
        """Map points (..., 3) from the sensor frame to the tank frame."""
        return np.asarray(points_sensor_m) @ self.rotation.T + self.position_m

    def to_sensor(self, points_tank_m: np.ndarray) -> np.ndarray:
        """Map points (..., 3) from the tank frame to the sensor frame."""
        return (np.asarray(points_tank_m) - self.position_m) @ self.rotation

    def as_array(self) -> np.ndarray:
        return np.array([self.x_m, self.y_m, self.z_m, self.yaw_rad], dtype=float)

    @classmethod
    def from_array(cls, a) -> "Pose":
        a = np.asarray(a, dtype=float).ravel()
        if a.size != 4:
            raise ValueError(f"a pose needs 4 numbers (x_m, y_m, z_m, yaw_rad), got {a.size}")
        return cls(*map(float, a))

    @classmethod
    def parse(cls, text: str) -> "Pose":
        """Parse ``"X,Y,Z,YAW"`` (m, m, m, rad) as given on the command line."""
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            raise ValueError(f"pose {text!r}: expected X,Y,Z,YAW as numbers (m, m, m, rad)") from None
        if len(values) != 4:
            raise ValueError(f"pose {text!r}: expected 4 numbers X,Y,Z,YAW, got {len(values)}")
        return cls(*values)


def poses_array(poses) -> np.ndarray:
    """Any sequence of poses (``Pose`` objects or rows x, y, z, yaw) as a (P, 4) float array."""
    if isinstance(poses, Pose):
        return poses.as_array()[None, :]
    rows = [p.as_array() if isinstance(p, Pose) else np.asarray(p, dtype=float) for p in poses]
    arr = np.asarray(rows, dtype=float).reshape(-1, 4)
    if not np.all(np.isfinite(arr)):
        raise ValueError("poses contain non-finite values")
    return arr


def sensor_to_tank(points_sensor_m: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Map sensor-frame points (m, 3) into the tank frame for each pose: (P, m, 3)."""
    poses = poses_array(poses)
    R = rotation_z(poses[:, 3])
    return np.einsum("pij,mj->pmi", R, np.asarray(points_sensor_m, dtype=float)) + poses[:, None, :3]
