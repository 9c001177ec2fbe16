"""A flat insulating face of the tank taken into the Green's function by its image, instead of a mesh.

Where the water lies on one side of a plane face ``P`` of its boundary (a box's wall, a tank's floor or free
surface) and no current crosses ``P``, the Neumann Green's function of the half-space,

    G_P(x, y) = G(x, y) + G(x*, y),     x* the mirror image of x in P,

has ``dG_P/dn_y = 0`` on ``P``, so Green's representation with ``G_P`` holds over the boundary less ``P``
(Jackson, *Classical Electrodynamics*, 3rd ed., 2.1; the method of images): ``P`` needs no triangles. With
constant densities on flat triangles the image term of triangle ``T_j`` at ``x_i`` is the ordinary layer of
``T_j`` at ``x_i*`` (a reflection keeps the solid angle's sign when it reflects the normal too), so every block
of the collocation system gets the same matrices at the reflected collocation points, none of them singular: the
water is on one side of ``P``, so ``x_i*`` is never on the water's boundary but on ``P`` itself.

Several faces at once, where they are mutually perpendicular (a box's corner: a wall, the next wall and the
floor): the reflections in them commute and generate a group of ``2^k`` isometries, and the Green's function
sums ``G(g x, y)`` over all of them (:class:`ImageGroup`); two parallel faces would need an infinite series
and are refused.

What this buys: a sensor a few millimetres from a wall needs a tank mesh graded to the gap on that wall, ten
times a mid-tank pose's triangles, and still carries that mesh's error (0.04 % at 5 mm); with the wall as an
image plane the rest of the tank is as coarse as in mid-tank and the error is gone. What it costs: the
sensor's own image, a block the sensor's size compressed to low rank, 4-6 s of CPU for an 8 400-triangle
sensor, so that beyond about 2 cm from the wall the mesh is cheaper (``esense study image_plane``).

Example
-------
>>> import numpy as np
>>> from electrosense.meshes import Tank
>>> from electrosense.meshes.tank_mesh import mesh_tank
>>> mesh = mesh_tank(Tank((0.4, 0.3, 0.3)), 0.05)
>>> plane = image_plane_of(mesh, "wall_x-")
>>> plane.reflect(np.array([[-0.19, 0.0, 0.0]])).round(3).tolist()    # 1 cm from the wall at x = -0.2 m
[[-0.21, 0.0, 0.0]]
>>> rest, group = split_image_faces(mesh, ("wall_x-", "floor"))      # a corner: three images
>>> [g.round(3).tolist() for g in group.images(np.array([[-0.19, 0.0, -0.14]]))]
[[[-0.21, 0.0, -0.14]], [[-0.19, 0.0, -0.16]], [[-0.21, 0.0, -0.16]]]
>>> rest.n_triangles < mesh.n_triangles, "wall_x-" in rest.region_names
(True, True)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ImagePlane", "ImageGroup", "image_plane_of", "split_image_faces", "ImageFaceError"]

#: the face's vertices off its plane, relative to the mesh's extent, above which it is not a plane
PLANE_TOL = 1e-9


class ImageFaceError(ValueError):
    """A face that cannot be an image plane (not in the mesh, not flat, or water on both sides of it)."""


@dataclass(frozen=True)
class ImagePlane:
    """The plane ``(x - point_m) . normal = 0``, ``normal`` the unit normal out of the water."""

    point_m: np.ndarray
    normal: np.ndarray

    def reflect(self, points_m: np.ndarray) -> np.ndarray:
        """(N, 3) mirror images of ``points_m`` (N, 3) in the plane."""
        p = np.asarray(points_m, float)
        return p - 2.0 * ((p - self.point_m) @ self.normal)[:, None] * self.normal

    def distance_m(self, points_m: np.ndarray) -> np.ndarray:
        """(N,) distance of ``points_m`` from the plane, positive on the water's side."""
        return (self.point_m - np.asarray(points_m, float)) @ self.normal


@dataclass(frozen=True)
class ImageGroup:
    """The reflections in mutually perpendicular :class:`ImagePlane` s and all their products (``2^k - 1``
    images besides the identity)."""

    planes: tuple

    def images(self, points_m: np.ndarray) -> list:
        """The images of ``points_m`` (N, 3), one (N, 3) array per element of the group but the identity, in the
        order of the subsets' binary numbers (plane 0, plane 1, planes 0 and 1, ...)."""
        out = []
        for subset in range(1, 2 ** len(self.planes)):
            p = np.asarray(points_m, float)
            for k, plane in enumerate(self.planes):
                if subset >> k & 1:
                    p = plane.reflect(p)
            out.append(p)
        return out


def split_image_faces(mesh, region_names):
    """(the mesh without the regions ``region_names``, their :class:`ImageGroup`): each face as
    :func:`image_plane_of` takes it; faces that are not mutually perpendicular refused."""
    planes = []
    for name in region_names:
        plane = image_plane_of(mesh, name)
        for other_name, other in zip(region_names, planes):
            if abs(float(plane.normal @ other.normal)) > 1e-9:
                raise ImageFaceError(f"image planes: the faces {other_name!r} and {name!r} are not perpendicular "
                                     "(parallel faces would need an infinite series of images)")
        planes.append(plane)
    on_faces = np.isin(mesh.region, [mesh.region_index(name) for name in region_names])
    return mesh.select(~on_faces), ImageGroup(tuple(planes))


def image_plane_of(mesh, region_name: str) -> ImagePlane:
    """The plane of the region ``region_name`` of a closed mesh, its normal out of the water.

    Refuses (:class:`ImageFaceError`) a region the mesh does not have, one that is not flat, and one with
    parts of the rest of the mesh on both sides of its plane (the image would lie in the water).
    """
    if region_name not in mesh.region_names:
        raise ImageFaceError(f"image plane: the tank mesh has no face {region_name!r} "
                             f"(it has {', '.join(mesh.region_names)})")
    on_face = mesh.region_mask(region_name)
    if not on_face.any():
        raise ImageFaceError(f"image plane: the face {region_name!r} has no triangles")
    tri = mesh.triangles_m[on_face]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]).sum(axis=0)
    normal = cross / np.linalg.norm(cross)
    point = tri.reshape(-1, 3).mean(axis=0)
    extent = float(np.ptp(mesh.vertices_m, axis=0).max())
    off = np.abs((tri.reshape(-1, 3) - point) @ normal).max()
    if off > PLANE_TOL * extent + 1e-12:
        raise ImageFaceError(f"image plane: the face {region_name!r} is not flat ({off:.2e} m off its plane)")
    plane = ImagePlane(point, normal)
    if np.any(plane.distance_m(mesh.vertices_m) < -PLANE_TOL * extent - 1e-12):
        raise ImageFaceError(f"image plane: the tank lies on both sides of the face {region_name!r}")
    return plane
