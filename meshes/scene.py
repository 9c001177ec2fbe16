"""A scene: the sensor at a pose, optionally in a tank, with objects and electrodes of its own.

The sensor may be absent (``None``): a tank with field electrodes in its
walls (:mod:`electrosense.meshes.surface_electrodes`) is a scene too. Scene electrodes are
numbered after the sensor's electrodes.

A scene is geometry only. The water's conductivity and the electrodes'
contact impedance are physics and are passed to the solvers separately.

Example
-------
>>> from electrosense.meshes.scene import Scene
>>> from electrosense.meshes.sensor import preset
>>> from electrosense.meshes.tank import Tank
>>> from electrosense.meshes.pose import Pose
>>> scene = Scene(preset("angels-2"), Pose(0.0, 0.0, 0.0, 0.0), Tank((1.0, 1.0, 1.0)))
>>> scene.is_unbounded
False
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

from electrosense.meshes.cylinder_tank import CylinderTank
from electrosense.meshes.objects import SceneObject
from electrosense.meshes.pose import Pose
from electrosense.meshes.sensor import SensorDescription
from electrosense.meshes.surface_electrodes import SurfaceElectrode
from electrosense.meshes.tank import Tank

__all__ = ["Scene"]


@dataclass(frozen=True)
class Scene:
    """Sensor (or ``None``) + pose (tank frame) + optional tank (``None``: unbounded water) + objects + electrodes."""

    sensor: SensorDescription | None
    pose: Pose = field(default_factory=Pose)
    tank: Tank | CylinderTank | None = None
    objects: tuple[SceneObject, ...] = ()
    electrodes: tuple[SurfaceElectrode, ...] = ()

    def __post_init__(self):
        object.__setattr__(self, "electrodes", tuple(self.electrodes))
        if self.sensor is None and not self.electrodes:
            raise ValueError("a scene needs a sensor or electrodes of its own")
        if self.electrodes and self.tank is None:
            raise ValueError("scene electrodes sit on a tank's boundary: the scene has no tank")

    @property
    def n_sensor_electrodes(self) -> int:
        return 0 if self.sensor is None else self.sensor.n_electrodes

    @property
    def n_electrodes(self) -> int:
        """All electrodes: the sensor's (1..n_s) and the scene's (n_s + 1...)."""
        return self.n_sensor_electrodes + len(self.electrodes)

    @property
    def is_unbounded(self) -> bool:
        return self.tank is None

    def at(self, pose: Pose) -> "Scene":
        """The same scene with the sensor moved to ``pose``."""
        return replace(self, pose=pose)
