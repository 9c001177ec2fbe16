"""Electrodes of a scene: discs flush with a tank's wall or floor, plates, and metal bodies in the water.

A sensor carries its own electrodes (:mod:`electrosense.meshes.sensor`). A scene may also
have electrodes of its own, on the tank (field electrodes in the walls, a
ground electrode on the floor, a plate covering a whole wall):

* :class:`DiscElectrode`: a disc of ``radius_m`` centred at ``centre_m`` (tank
  frame), flush with the boundary the centre lies on. A screw head or a small
  button is modelled by the disc of its wetted radius.
* :class:`PlateElectrode`: a whole boundary region of the tank (``"floor"``,
  ``"wall_x+"``, ``"free_surface"`` ...) is one electrode.
* :class:`BodyElectrode`: a metal body in the water (a sphere, a vertical
  rod, a block), its whole surface one electrode: a reference electrode hung
  in the tank, a ball electrode, a screw's tip standing off the wall. It has
  no electrode/insulator edge to grade towards.

Scene electrodes are numbered after the sensor's: with a sensor of n
electrodes, the scene's first electrode is n + 1 (1 without a sensor).

Meshes are graded towards every electrode edge, where the current density is
singular (~ r^-1/2): :func:`electrode_size_function` gives the target edge
length ``h(p) = min(h_far, min_k(h_k + grading * d_k(p)))`` with ``d_k`` the
distance to electrode k's rim and ``h_k = edge_fraction * radius_k``.

Example
-------
>>> import numpy as np
>>> from electrosense.meshes.surface_electrodes import DiscElectrode, electrode_size_function
>>> e = DiscElectrode(centre_m=(0.15, 0.0, -0.05), radius_m=0.004)
>>> h = electrode_size_function([e], h_far_m=0.03)
>>> h(np.array([[0.15, 0.004, -0.05], [0.15, 0.1, 0.1]])).round(4).tolist()
[0.001, 0.03]
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

__all__ = ["DiscElectrode", "PlateElectrode", "BodyElectrode", "SurfaceElectrode", "electrode_size_function",
           "DEFAULT_EDGE_FRACTION", "DEFAULT_ELECTRODE_GRADING", "disc_rim_nodes", "rim_offsets",
           "RIM_GRADING_RATIO", "RIM_FIRST_ROW_EXPONENT"]

#: edge length at an electrode's rim, as a fraction of its radius
DEFAULT_EDGE_FRACTION = 0.25
#: growth of the edge length per metre away from an electrode rim
DEFAULT_ELECTRODE_GRADING = 0.5


@dataclass(frozen=True)
class DiscElectrode:
    """A disc electrode of radius ``radius_m`` flush with the tank boundary at ``centre_m`` (tank frame)."""

    centre_m: tuple[float, float, float]
    radius_m: float
    name: str = ""

    def __post_init__(self):
        c = tuple(float(v) for v in self.centre_m)
        if len(c) != 3 or not all(np.isfinite(c)):
            raise ValueError(f"disc electrode {self.name!r}: centre_m must be 3 finite numbers, got {self.centre_m}")
        object.__setattr__(self, "centre_m", c)
        r = float(self.radius_m)
        if not (np.isfinite(r) and r > 0):
            raise ValueError(f"disc electrode {self.name!r}: radius_m must be positive, got {self.radius_m}")
        object.__setattr__(self, "radius_m", r)


@dataclass(frozen=True)
class PlateElectrode:
    """A whole boundary region of the tank (``"floor"``, ``"wall_x+"``, ``"free_surface"``...) as one electrode."""

    region: str
    name: str = ""


@dataclass(frozen=True)
class BodyElectrode:
    """A metal body in the water, its whole surface one electrode: a ball, a vertical rod, a block.

    ``body`` is a :class:`~electrosense.meshes.objects.Sphere`,
    :class:`~electrosense.meshes.objects.Cylinder` (a rod, axis vertical) or
    :class:`~electrosense.meshes.objects.Box` (tank frame).

    >>> from electrosense.meshes.objects import Sphere
    >>> BodyElectrode(Sphere((0.0, 0.0, 0.0), radius_m=0.01), "reference").centre_m
    (0.0, 0.0, 0.0)
    """

    body: object
    name: str = ""

    def __post_init__(self):
        from electrosense.meshes.objects import Box, Cylinder, Sphere

        if not isinstance(self.body, (Sphere, Cylinder, Box)):
            raise ValueError(f"body electrode {self.name!r}: body must be a Sphere, Cylinder or Box, "
                             f"got {type(self.body).__name__}")

    @property
    def centre_m(self) -> tuple[float, float, float]:
        return self.body.centre_m


SurfaceElectrode = DiscElectrode | PlateElectrode | BodyElectrode


def electrode_size_function(electrodes: Sequence, h_far_m: float, edge_fraction: float = DEFAULT_EDGE_FRACTION,
                            grading: float = DEFAULT_ELECTRODE_GRADING,
                            base: Callable[[np.ndarray], np.ndarray] | None = None):
    """Target edge length h(p) (m) at points (..., 3), graded towards every disc electrode's rim.

    ``base`` (another size function) is combined by the minimum; plates add
    no grading here (their edges are the region's edges).
    """
    discs = [e for e in electrodes if isinstance(e, DiscElectrode)]
    if not h_far_m > 0:
        raise ValueError(f"h_far_m must be positive, got {h_far_m}")
    centres = np.array([d.centre_m for d in discs], float).reshape(-1, 3)
    radii = np.array([d.radius_m for d in discs], float)
    h_edge = edge_fraction * radii

    def h(p):
        p = np.asarray(p, dtype=float)
        q = p.reshape(-1, 3)
        out = np.full(len(q), float(h_far_m))
        if len(discs):
            d = np.abs(np.linalg.norm(q[:, None, :] - centres[None], axis=2) - radii[None])
            out = np.minimum(out, np.min(h_edge[None] + grading * d, axis=1))
        if base is not None:
            out = np.minimum(out, base(q))
        return out.reshape(p.shape[:-1])

    return h


#: ratio of the radial sizes of neighbouring rows of elements across a rim, towards the rim (geometric grading)
RIM_GRADING_RATIO = 0.5
#: exponent beta of the first row's radial size s0 = h_edge (h_edge / radius)^beta (see :func:`rim_offsets`)
RIM_FIRST_ROW_EXPONENT = 1.5


def rim_offsets(h_edge_m: float, radius_m: float, ratio: float = RIM_GRADING_RATIO,
                beta: float = RIM_FIRST_ROW_EXPONENT) -> np.ndarray:
    """Distances (m) from a rim of the rows of nodes that resolve the edge singularity across it.

    The current density varies as r^-1/2 across the rim and not along it, so
    rows of thin elements follow the rim on both sides, fine across it and
    ``h_edge`` along it. Their radial sizes form a geometric series of
    ``ratio`` towards the rim, from about ``h_edge / 2`` down to the first
    row's ``s0 = h_edge * min(ratio, (h_edge / radius)^beta)``. The element
    touching the rim does not resolve the r^-1/2 density: its share of the
    error scales as (s0 / radius)^(1/2) = (h_edge / radius)^((1 + beta) / 2).
    With beta = 1.5 that falls faster than first order in h_edge, so refining
    the rim refines its rows with it (no row size tied to one mesh); beta = 2
    (second order) makes the rows at the default rim thinner than the BEM's
    mesh-quality floor (1 degree) allows. Newman's disc (``esense study
    disc_electrode``) converges as N^-1 (h^2) with this grading.

    >>> rim_offsets(1.0, 4.0).tolist()     # h_edge = radius / 4: rows of h/8, h/4, h/2
    [0.125, 0.375, 0.875]
    """
    s0 = h_edge_m * min(ratio, (h_edge_m / radius_m) ** beta)
    out, d, step = [], 0.0, s0
    while step <= ratio * h_edge_m * (1 + 1e-9):
        d += step
        out.append(d)
        step /= ratio
    return np.array(out)


def disc_rim_nodes(centre_uv, radius_m: float, h_edge_m: float, n_min: int = 12, rows: bool = True) -> np.ndarray:
    """(R, N, 2) rows of nodes along a disc's rim in its surface's (u, v) plane; row 0 is the rim.

    The rim polygon's vertices lie on the circle whose inscribed N-gon has the
    disc's area, so the polygonal electrode has the true area; the further
    rows (:func:`rim_offsets`) lie inside and outside at the same angles.
    """
    n = max(n_min, int(np.ceil(2 * np.pi * radius_m / h_edge_m)))
    r_eq = radius_m * np.sqrt(2 * np.pi / (n * np.sin(2 * np.pi / n)))
    t = 2 * np.pi * np.arange(n) / n
    d = rim_offsets(h_edge_m, radius_m) if rows else np.zeros(0)
    d = d[d < 0.5 * r_eq]
    radii = np.r_[r_eq, r_eq - d, r_eq + d]
    unit = np.stack([np.cos(t), np.sin(t)], axis=1)
    return np.asarray(centre_uv, float) + radii[:, None, None] * unit[None]
