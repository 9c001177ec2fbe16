"""Objects in the water: spheres, boxes and cylinders, insulating or conducting.

An object's material is its conductivity in S/m: ``0.0`` is a perfect
insulator, ``math.inf`` a perfect conductor (a floating equipotential). The
BEM handles these two limits; the PSM's dipole term takes any value.

Example
-------
>>> from electrosense.meshes.objects import Sphere
>>> Sphere(centre_m=(0.2, 0.0, 0.0), radius_m=0.02, conductivity_S_per_m=float("inf")).is_conducting
True
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Sphere", "Box", "Cylinder", "SceneObject", "parse_material"]

INSULATING = 0.0
CONDUCTING = math.inf


def parse_material(value) -> float:
    """``"insulating"``, ``"conducting"`` or a conductivity in S/m, as a float."""
    if isinstance(value, str):
        v = value.strip().lower()
        if v in ("insulating", "insulator"):
            return INSULATING
        if v in ("conducting", "conductor", "metal"):
            return CONDUCTING
        try:
            value = float(v)
        except ValueError:
            raise ValueError(f"material {value!r}: expected insulating, conducting or a conductivity in S/m") from None
    value = float(value)
    if value < 0 or math.isnan(value):
        raise ValueError(f"object conductivity must be >= 0 S/m, got {value}")
    return value


@dataclass(frozen=True)
class _Object:
    centre_m: tuple[float, float, float]
    conductivity_S_per_m: float = INSULATING
    name: str = ""

    def __post_init__(self):
        c = tuple(float(v) for v in self.centre_m)
        if len(c) != 3 or not all(np.isfinite(c)):
            raise ValueError(f"object {self.name or type(self).__name__}: centre must be 3 finite numbers, got {self.centre_m}")
        object.__setattr__(self, "centre_m", c)
        object.__setattr__(self, "conductivity_S_per_m", parse_material(self.conductivity_S_per_m))
        for key in ("radius_m", "height_m", "size_m"):   # the shape's lengths, of the subclass that has them
            if hasattr(self, key):
                value = np.atleast_1d(np.asarray(getattr(self, key), dtype=float))
                if not (np.all(np.isfinite(value)) and np.all(value > 0)):
                    raise ValueError(f"object {self.label}: {key} must be positive (m), got {getattr(self, key)}")

    @property
    def is_conducting(self) -> bool:
        return math.isinf(self.conductivity_S_per_m)

    @property
    def is_insulating(self) -> bool:
        return self.conductivity_S_per_m == 0.0

    @property
    def label(self) -> str:
        return self.name or type(self).__name__.lower()


@dataclass(frozen=True)
class Sphere(_Object):
    """A sphere of radius ``radius_m`` centred at ``centre_m`` (tank frame)."""

    radius_m: float = 0.01

    @property
    def bounding_radius_m(self) -> float:
        return float(self.radius_m)


@dataclass(frozen=True)
class Box(_Object):
    """An axis-aligned box (after rotation by ``yaw_rad`` about z) of edge lengths ``size_m``."""

    size_m: tuple[float, float, float] = (0.02, 0.02, 0.02)
    yaw_rad: float = 0.0

    @property
    def bounding_radius_m(self) -> float:
        return 0.5 * float(np.linalg.norm(self.size_m))


@dataclass(frozen=True)
class Cylinder(_Object):
    """A cylinder of radius ``radius_m`` and height ``height_m``, axis along z (vertical pole)."""

    radius_m: float = 0.01
    height_m: float = 0.1

    @property
    def bounding_radius_m(self) -> float:
        return float(np.hypot(self.radius_m, 0.5 * self.height_m))


SceneObject = Sphere | Box | Cylinder
