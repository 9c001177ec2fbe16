"""Potential and current density in the water, from a surface solution.

Green's representation at a point ``x`` in the water (normals out of the water):

    u(x) = sum_j S_j(x) q_j - sum_j D_j(x) u_j,

with the exact single and double layers of every triangle
(:mod:`electrosense.bem.operators`), so points close to the surface are as accurate as
far ones. The current density ``J = -sigma grad u`` is taken by central
differences of that representation (step 1e-6 of the sensor's size).

Example
-------
>>> from electrosense.meshes import Scene, preset
>>> from electrosense.bem.solve import solve_scene
>>> sol = solve_scene(Scene(preset("angels-2")), 1.0)       # doctest: +SKIP
>>> sol.potential_at([[0.0, 0.05, 0.0]])                      # doctest: +SKIP
"""
from __future__ import annotations

import numpy as np

from electrosense.bem.operators import TriangleSet, layer_matrices

__all__ = ["potential_at", "current_density_at", "surface_polydata", "plane_points"]

_CHUNK = 2048


def potential_at(solution, points_m, V) -> np.ndarray:
    """Potential (V) at points (..., 3) in the water for electrode potentials ``V``."""
    pts = np.asarray(points_m, dtype=float)
    shape = pts.shape[:-1]
    pts = pts.reshape(-1, 3)
    u, q = solution.surface(V)
    tris = TriangleSet(solution.boundary.triangles_m)
    out = np.empty(len(pts))
    for a in range(0, len(pts), _CHUNK):
        S, D = layer_matrices(pts[a:a + _CHUNK], tris)
        out[a:a + _CHUNK] = S @ q - D @ u
    return out.reshape(shape)


def current_density_at(solution, points_m, V, step_m: float | None = None) -> np.ndarray:
    """Current density ``-sigma grad u`` (A/m^2), shape (..., 3), at points in the water.

    ``step_m``: the central differences' step; default 1e-6 of the sensor's size (of the whole boundary's in a
    scene without a sensor: a tank with electrodes of its own)."""
    pts = np.asarray(points_m, dtype=float)
    shape = pts.shape
    pts = pts.reshape(-1, 3)
    if step_m is None:
        tris = solution.boundary.triangles_m
        tris = tris[: solution.boundary.n_sensor] if solution.boundary.n_sensor else tris
        extent = np.ptp(tris.reshape(-1, 3), axis=0).max()
        step_m = 1e-6 * extent
    shifted = np.concatenate([pts + s * step_m * e for e in np.eye(3) for s in (1.0, -1.0)])
    u = potential_at(solution, shifted, V).reshape(3, 2, len(pts))
    grad = (u[:, 0] - u[:, 1]).T / (2 * step_m)
    return (-solution.sigma_S_per_m * grad).reshape(shape)


def plane_points(centre_m, u_axis, v_axis, half_width_m: float, half_height_m: float, n_u: int = 101, n_v: int = 101):
    """A (n_v, n_u, 3) grid of points on a plane, for field pictures."""
    c, eu, ev = (np.asarray(a, dtype=float) for a in (centre_m, u_axis, v_axis))
    s = np.linspace(-half_width_m, half_width_m, n_u)
    t = np.linspace(-half_height_m, half_height_m, n_v)
    return c + s[None, :, None] * eu + t[:, None, None] * ev


def surface_polydata(solution, V):
    """``pyvista.PolyData`` of the boundary with cell data ``potential_V``,
    ``current_density_A_per_m2`` (into the water on electrodes, 0 on insulators),
    ``electrode`` and ``part``."""
    import pyvista as pv

    wb = solution.boundary
    mesh = wb.mesh
    u, q = solution.surface(V)
    faces = np.hstack([np.full((mesh.n_triangles, 1), 3), mesh.faces]).ravel()
    poly = pv.PolyData(mesh.vertices_m, faces)
    poly.cell_data["potential_V"] = u
    poly.cell_data["current_density_A_per_m2"] = solution.sigma_S_per_m * q
    poly.cell_data["electrode"] = wb.electrode
    poly.cell_data["part"] = wb.part
    return poly
