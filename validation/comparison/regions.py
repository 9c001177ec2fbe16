"""Regions of a path: mid-tank, near a wall, the floor, the free surface or an object.

Each pose is given one label, from the distance between the sensor's
electrodes and the boundaries of the scene:

* ``"near object_k"`` (or ``"near <name>"``) when an electrode centre is
  within ``near_object_m`` of an object's bounding sphere surface;
* otherwise ``"near wall_x-"``, ..., ``"near floor"``, ``"near free_surface"``
  (the boundary names of the tank's ``region_names``: :data:`electrosense.meshes.tank.TANK_REGIONS` of a box, a
  cylinder's wall, floor and free surface) for the nearest
  tank boundary when an electrode centre is within ``near_wall_m`` of it;
* otherwise ``"mid-tank"`` (``"open water"`` when there is no tank).

Distances are measured from the electrode centres (the sensing parts) in the
tank frame; without a sensor, from the pose's centre. The defaults, 0.10 m
for walls and objects, are half the length of the paper's 20 cm sensors: the
resistance curves of the paper rise over the last 0.1 m before a wall.

Example
-------
>>> import numpy as np
>>> from electrosense.meshes.tank import Tank
>>> poses = np.array([[0.0, 0, 0, 0], [0.45, 0, 0, 0]])
>>> path_regions(poses, Tank((1.0, 1.0, 1.0))).tolist()
['mid-tank', 'near wall_x+']
"""
from __future__ import annotations

import numpy as np

from electrosense.meshes.pose import poses_array, sensor_to_tank

__all__ = ["path_regions", "NEAR_WALL_M", "NEAR_OBJECT_M", "MID_TANK", "OPEN_WATER"]

NEAR_WALL_M = 0.10
NEAR_OBJECT_M = 0.10
MID_TANK = "mid-tank"
OPEN_WATER = "open water"


def _sensing_points(poses: np.ndarray, sensor=None) -> np.ndarray:
    """(P, m, 3) electrode centres in the tank frame (or the pose centres, m = 1)."""
    if sensor is None:
        return poses[:, None, :3]
    return sensor_to_tank(sensor.electrode_centres_m, poses)


def path_regions(
    poses,
    tank=None,
    objects=(),
    sensor=None,
    near_wall_m: float = NEAR_WALL_M,
    near_object_m: float = NEAR_OBJECT_M,
) -> np.ndarray:
    """One region label per pose (object first, then the nearest tank boundary).

    Parameters
    ----------
    poses : (P, 4) array
        Sensor poses (x_m, y_m, z_m, yaw_rad) in the tank frame.
    tank : meshes.tank.Tank or None
        ``None`` for unbounded water.
    objects : sequence of meshes.objects objects
        Known objects; their bounding spheres set the distance.
    sensor : meshes.sensor.SensorDescription, optional
        When given, distances are from its electrode centres.
    near_wall_m, near_object_m : float
        Thresholds (m).

    Returns
    -------
    (P,) array of str
    """
    if near_wall_m < 0 or near_object_m < 0:
        raise ValueError(f"region thresholds must be >= 0 m, got near_wall_m={near_wall_m}, near_object_m={near_object_m}")
    poses = poses_array(poses)
    pts = _sensing_points(poses, sensor)
    labels = np.full(len(poses), OPEN_WATER if tank is None else MID_TANK, dtype=object)
    if tank is not None:
        d = tank.distance_to_boundary_m(pts).min(axis=1)  # (P, 6): closest electrode per boundary
        nearest = d.argmin(axis=1)
        near = d[np.arange(len(poses)), nearest] <= near_wall_m
        names = np.array([f"near {r}" for r in tank.region_names], dtype=object)
        labels[near] = names[nearest[near]]
    for k, obj in enumerate(objects, start=1):
        centre = np.asarray(obj.centre_m, dtype=float)
        gap = np.linalg.norm(pts - centre, axis=-1).min(axis=1) - obj.bounding_radius_m
        name = getattr(obj, "name", "") or f"object_{k}"
        labels[gap <= near_object_m] = f"near {name}"
    return labels.astype(str)
