"""A scene: the sensor at a pose, optionally in a tank, with objects.

A scene is geometry only. The water's conductivity and the electrodes'
contact impedance are physics and are passed to the solvers separately.

Example
-------
>>> from meshes.scene import Scene
>>> from meshes.sensor import preset
>>> from meshes.tank import Tank
>>> from meshes.pose import Pose
>>> scene = Scene(preset("angels-2"), Pose(0.0, 0.0, 0.0, 0.0), Tank((1.0, 1.0, 1.0)))
>>> scene.is_unbounded
False
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

from .objects import SceneObject
from .pose import Pose
from .sensor import SensorDescription
from .tank import Tank

__all__ = ["Scene"]


@dataclass(frozen=True)
class Scene:
    """Sensor + pose (tank frame) + optional tank (``None``: unbounded water) + objects."""

    sensor: SensorDescription
    pose: Pose = field(default_factory=Pose)
    tank: Tank | None = None
    objects: tuple[SceneObject, ...] = ()

    @property
    def is_unbounded(self) -> bool:
        return self.tank is None

    def at(self, pose: Pose) -> "Scene":
        """The same scene with the sensor moved to ``pose``."""
        return replace(self, pose=pose)
