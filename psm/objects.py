"""Small spheres in the sensor's field: the dipole term of the PSM.

A sphere of radius b and conductivity sigma_o at x_o in the field E0 of the
sensor acts as a dipole (Rasnow 1996): it adds the potential
``chi b^3 E0(x_o) . (x - x_o) / |x - x_o|^3`` with the contrast
``chi = (sigma_o - sigma) / (sigma_o + 2 sigma)`` (1 for a perfect conductor,
-1/2 for an insulator). In potential coefficients (V = R I / 4 pi sigma)::

    dR_pq = -chi b^3 grad_y G(y, c_p) . grad_y G(y, c_q),   y = x_o,

with G = 1/|y - c| in free space, giving the free-space form
``chi b^3 (c_p - x_o).(x_o - c_q) / (|c_p - x_o|^3 |x_o - c_q|^3)``; in a
tank G also carries the image sources (the field of the walls' images
polarises the object, and the dipole has images). The object's own
reaction to its images is neglected (first order in b^3 / distance^3).

Example
-------
>>> contrast(float("inf"), 0.05), contrast(0.0, 0.05)
(1.0, -0.5)
"""
from __future__ import annotations

import math

import numpy as np

from electrosense.meshes.objects import Sphere

__all__ = ["contrast", "object_terms"]


def contrast(conductivity_S_per_m: float, sigma_S_per_m: float) -> float:
    """``chi = (sigma_o - sigma) / (sigma_o + 2 sigma)``; 1 for ``inf`` (conducting), -1/2 for 0."""
    if math.isinf(conductivity_S_per_m):
        return 1.0
    return (conductivity_S_per_m - sigma_S_per_m) / (conductivity_S_per_m + 2.0 * sigma_S_per_m)


def object_terms(objects, sigma_S_per_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centres (O, 3), radii (O,) and ``-chi b^3`` (O,) of the objects (tank frame).

    Only spheres have a dipole term; any other object is refused.
    """
    objects = tuple(objects)
    for k, obj in enumerate(objects, start=1):
        if not isinstance(obj, Sphere):
            raise ValueError(
                f"object {k} ({getattr(obj, 'label', type(obj).__name__)}): the PSM's dipole term "
                f"handles spheres only, got a {type(obj).__name__}"
            )
    centres = np.array([o.centre_m for o in objects], dtype=float).reshape(-1, 3)
    radii = np.array([o.radius_m for o in objects], dtype=float)
    coef = np.array([-contrast(o.conductivity_S_per_m, sigma_S_per_m) * o.radius_m**3 for o in objects], dtype=float)
    return centres, radii, coef
