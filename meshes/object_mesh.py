"""Meshes of the objects in the water: spheres, boxes and cylinders.

Every object mesh is closed, watertight, in the tank frame, with electrode
label 0 and one region (``"object_<i>"`` in a scene); its normals point out
of the object, into the water.

* Sphere: a geodesic (subdivided icosahedron) sphere, vertices on the
  sphere, near-equilateral triangles.
* Box: six planar faces meshed with shared edge nodes, yawed about z.
* Cylinder (vertical axis): a staggered band of near-equilateral triangles
  on the side and two meshed discs sharing its rim nodes.

Example
-------
>>> from electrosense.meshes.objects import Sphere
>>> from electrosense.meshes.object_mesh import mesh_object
>>> m = mesh_object(Sphere(centre_m=(0.1, 0.0, 0.0), radius_m=0.02), edge_length_m=0.005)
>>> m.region_names, m.to_trimesh().is_watertight
(('object',), True)
"""
from __future__ import annotations

import numpy as np

from electrosense.meshes.labelled_mesh import LabelledMesh
from electrosense.meshes.objects import Box, Cylinder, Sphere
from electrosense.meshes.pose import rotation_z
from electrosense.meshes.tank_mesh import _weld, graded_size_function, mesh_axis_box, mesh_convex_polygon

__all__ = ["mesh_object", "mesh_sphere", "mesh_box", "mesh_cylinder", "default_object_edge_length_m"]


def default_object_edge_length_m(obj) -> float:
    """Default edge length: a sixth of the object's smallest feature size (m)."""
    if isinstance(obj, Sphere):
        return obj.radius_m / 4
    if isinstance(obj, Box):
        return min(obj.size_m) / 4
    if isinstance(obj, Cylinder):
        return min(obj.radius_m / 2, obj.height_m / 3)
    raise TypeError(f"unknown object type {type(obj).__name__} (Sphere, Box or Cylinder)")


def _check_positive(obj, **lengths):
    for key, value in lengths.items():
        values = np.atleast_1d(np.asarray(value, dtype=float))
        if not (np.all(np.isfinite(values)) and np.all(values > 0)):
            raise ValueError(f"object {obj.label}: {key} must be positive, got {value}")


def mesh_sphere(sphere: Sphere, edge_length_m: float, region_name: str = "object") -> LabelledMesh:
    """Geodesic sphere with edges close to ``edge_length_m`` (at least 80 triangles)."""
    import trimesh

    _check_positive(sphere, radius_m=sphere.radius_m, edge_length_m=edge_length_m)
    # an icosahedron's edge is 1.0515 r; every subdivision halves it
    level = int(np.clip(np.ceil(np.log2(1.0515 * sphere.radius_m / edge_length_m)), 1, 7))
    ico = trimesh.creation.icosphere(subdivisions=level, radius=sphere.radius_m)
    vertices = np.asarray(ico.vertices) + np.asarray(sphere.centre_m)
    return LabelledMesh(vertices, np.asarray(ico.faces), None, None, (region_name,))


def mesh_box(box: Box, edge_length_m: float, region_name: str = "object") -> LabelledMesh:
    """Box of edge lengths ``size_m``, yawed by ``yaw_rad`` about z, centred at ``centre_m``."""
    _check_positive(box, size_m=box.size_m, edge_length_m=edge_length_m)
    half = 0.5 * np.asarray(box.size_m, dtype=float)
    local = mesh_axis_box(-half, half, graded_size_function(edge_length_m))
    vertices = local.vertices_m @ rotation_z(box.yaw_rad).T + np.asarray(box.centre_m)
    return LabelledMesh(vertices, local.faces, None, None, (region_name,))


def mesh_cylinder(cylinder: Cylinder, edge_length_m: float, region_name: str = "object") -> LabelledMesh:
    """Vertical cylinder (axis along z) of radius ``radius_m`` and height ``height_m``."""
    _check_positive(cylinder, radius_m=cylinder.radius_m, height_m=cylinder.height_m, edge_length_m=edge_length_m)
    r, height = cylinder.radius_m, cylinder.height_m
    n_theta = max(12, int(np.ceil(2 * np.pi * r / edge_length_m)))
    d_theta = 2 * np.pi / n_theta
    n_rows = max(1, int(np.round(height / (0.866 * 2 * r * np.sin(d_theta / 2)))))
    # side: rows of n_theta nodes, every other row shifted by half a step -> near-equilateral
    k = np.arange(n_theta)
    rows = []
    for j in range(n_rows + 1):
        theta = (k + 0.5 * (j % 2)) * d_theta
        z = -0.5 * height + height * j / n_rows
        rows.append(np.stack([r * np.cos(theta), r * np.sin(theta), np.full(n_theta, z)], axis=1))
    side_vertices = np.concatenate(rows)
    faces = []
    for j in range(n_rows):
        a = j * n_theta + k  # lower row
        b = (j + 1) * n_theta + k  # upper row
        a1, b1 = j * n_theta + (k + 1) % n_theta, (j + 1) * n_theta + (k + 1) % n_theta
        if j % 2 == 0:  # upper row shifted forward: triangles (a, a1, b) and (a1, b1, b)
            faces += [np.stack([a, a1, b], 1), np.stack([a1, b1, b], 1)]
        else:  # lower row shifted forward
            faces += [np.stack([a, b1, b], 1), np.stack([a, a1, b1], 1)]
    faces = [np.concatenate(faces)]
    vertices = [side_vertices]
    offset = len(side_vertices)
    size_uv = graded_size_function(edge_length_m)
    size_2d = lambda q: size_uv(np.c_[q, np.zeros(len(q))])  # noqa: E731
    for rim, up in ((rows[0], False), (rows[-1], True)):
        points_uv, tri = mesh_convex_polygon(rim[:, :2], size_2d)
        cap = np.c_[points_uv, np.full(len(points_uv), rim[0, 2])]
        cap[: len(rim)] = rim  # the rim nodes exactly as on the side
        vertices.append(cap)
        faces.append((tri if up else tri[:, ::-1]) + offset)
        offset += len(cap)
    vertices_m, faces_all = _weld(np.concatenate(vertices), np.concatenate(faces))
    return LabelledMesh(vertices_m + np.asarray(cylinder.centre_m), faces_all, None, None, (region_name,))


def mesh_object(obj, edge_length_m: float | None = None, region_name: str = "object") -> LabelledMesh:
    """Closed mesh of a sphere, box or cylinder in the tank frame (normals into the water).

    Parameters
    ----------
    obj : Sphere, Box or Cylinder
    edge_length_m : float, optional
        Target edge length (default :func:`default_object_edge_length_m`).
    region_name : str
        Name of the mesh's single region (``"object_<i>"`` in a scene).
    """
    h = default_object_edge_length_m(obj) if edge_length_m is None else float(edge_length_m)
    if isinstance(obj, Sphere):
        return mesh_sphere(obj, h, region_name)
    if isinstance(obj, Box):
        return mesh_box(obj, h, region_name)
    if isinstance(obj, Cylinder):
        return mesh_cylinder(obj, h, region_name)
    raise TypeError(f"cannot mesh {type(obj).__name__}: expected Sphere, Box or Cylinder")
