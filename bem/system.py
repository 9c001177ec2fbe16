"""The collocation system of the direct formulation on the water domain.

With ``u`` the potential and ``q = du/dn`` its normal derivative along the
normal OUT OF THE WATER, Green's representation at the centroid ``x_i`` of
every triangle (a smooth point of a flat face: free term 1/2) reads

    sum_j (1/2 delta_ij + D_ij) u_j  =  sum_j S_ij q_j,

``S`` the single layer and ``D`` the double layer (:mod:`electrosense.bem.operators`).
It holds for the closed tank and for unbounded water (u -> 0 at infinity).
Per triangle one of ``u_j``, ``q_j`` is known:

* insulating face: ``q_j = 0``, unknown ``u_j``;
* electrode ``k``: current density into the water ``sigma q_j`` (the water's
  current flows against the out-of-water normal), and behind a contact
  impedance ``z_c`` (ohm m^2) ``sigma q_j = (V_k - u_j) / z_c``, i.e.
  ``u_j = V_k - z_c sigma q_j`` (``z_c = 0``: ``u_j = V_k``); unknown ``q_j``;
* floating conductor ``c``: ``u_j = W_c`` (unknown), unknown ``q_j``, and one
  more equation ``sum_j a_j q_j = 0`` (no net current).

The unknowns on flux faces are scaled, ``x_j = l q_j`` with ``l`` the rms
triangle size, so that every column is O(1).

Example
-------
>>> import numpy as np, trimesh
>>> from electrosense.meshes.labelled_mesh import LabelledMesh
>>> from electrosense.bem.boundary_conditions import WaterBoundary
>>> s = trimesh.creation.icosphere(1)
>>> a = LabelledMesh(s.vertices * 0.01, s.faces, np.ones(80, int), None, ("sensor",))
>>> b = LabelledMesh(s.vertices * 0.01 + [0.1, 0, 0], s.faces, np.full(80, 2), None, ("sensor",))
>>> from electrosense.meshes.labelled_mesh import concatenate
>>> wb = WaterBoundary.from_meshes(concatenate([a, b]), check=False)
>>> system = assemble_system(wb, sigma_S_per_m=1.0)
>>> system.matrix.shape, system.rhs.shape
((160, 160), (160, 2))
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from electrosense.bem.boundary_conditions import BoundaryError, WaterBoundary
from electrosense.bem.conductance import check_conductivity
from electrosense.bem.memory import check_memory

__all__ = ["BemSystem", "assemble_system", "contact_impedances", "column_coefficients", "boundary_columns"]


def contact_impedances(contact_impedance_ohm_m2, n_electrodes: int) -> np.ndarray:
    """Per-electrode contact impedance (n,) from None, a float or a sequence (ohm m^2)."""
    if contact_impedance_ohm_m2 is None:
        return np.zeros(n_electrodes)
    z = np.asarray(contact_impedance_ohm_m2, dtype=float)
    if z.ndim == 0:
        z = np.full(n_electrodes, float(z))
    if z.shape != (n_electrodes,):
        raise ValueError(f"contact impedance: expected one value or {n_electrodes} (one per electrode), got {z.size}")
    if not np.all(np.isfinite(z)) or np.any(z < 0):
        raise ValueError(f"contact impedance must be finite and >= 0 ohm m^2, got {z.tolist()}")
    return z


def column_coefficients(boundary: WaterBoundary, sigma_S_per_m: float, z_c: np.ndarray, scale_m: float):
    """(c_single, c_double, group) of every triangle's column (see :func:`electrosense.bem.operators.mixed_system`)."""
    n = boundary.n_electrodes
    electrode, conductor = boundary.electrode, boundary.conductor
    c_single = np.zeros(boundary.n_triangles)
    c_double = np.ones(boundary.n_triangles)
    group = np.full(boundary.n_triangles, -1, np.int64)
    on_e = electrode > 0
    c_single[on_e] = -1.0 / scale_m
    c_double[on_e] = -z_c[electrode[on_e] - 1] * sigma_S_per_m / scale_m
    group[on_e] = electrode[on_e] - 1
    on_c = conductor >= 0
    c_single[on_c] = -1.0 / scale_m
    c_double[on_c] = 0.0
    group[on_c] = n + conductor[on_c]
    return c_single, c_double, group


@dataclass
class BemSystem:
    """``matrix @ [x; W] = rhs @ V`` for electrode potentials ``V`` (one column per electrode)."""

    matrix: np.ndarray
    rhs: np.ndarray
    scale_m: float
    z_c: np.ndarray
    n_conductors: int


def boundary_columns(boundary: WaterBoundary, sigma_S_per_m: float, contact_impedance_ohm_m2=None, triangles=None):
    """What every collocation solver of ``boundary`` starts from: ``(tris, z_c, scale_m, c_single, c_double, group)``.

    ``tris`` the :class:`~electrosense.bem.operators.TriangleSet` (``triangles`` if given), ``z_c`` the
    per-electrode contact impedance (ohm m^2), ``scale_m`` the mesh's own length scale (the square root of the
    mean triangle area) and the columns' coefficients of :func:`column_coefficients` at it.
    """
    from electrosense.bem.operators import TriangleSet  # numba kernels, loaded on first use

    z_c = contact_impedances(contact_impedance_ohm_m2, boundary.n_electrodes)
    tris = TriangleSet(boundary.triangles_m) if triangles is None else triangles
    scale = float(np.sqrt(np.mean(tris.areas)))
    return (tris, z_c, scale) + tuple(column_coefficients(boundary, sigma_S_per_m, z_c, scale))


def assemble_system(boundary: WaterBoundary, sigma_S_per_m: float, contact_impedance_ohm_m2=None,
                    triangles=None) -> BemSystem:
    """Assemble the dense mixed system on ``boundary`` (refusing what does not fit in memory)."""
    from electrosense.bem.operators import FAR, mixed_system  # numba kernels, loaded on first use

    sigma_S_per_m = check_conductivity(sigma_S_per_m)
    n = boundary.n_electrodes
    n_f, n_c = boundary.n_triangles, boundary.n_conductors
    check_memory(n_f + n_c, 1.1)
    tris, z_c, scale, c_single, c_double, group = boundary_columns(boundary, sigma_S_per_m,
                                                                  contact_impedance_ohm_m2, triangles)
    own = np.arange(n_f)
    # in a closed tank every row's solid angles must add up (the Neumann problem's compatibility):
    # the centroid rule beyond FAR diameters breaks that by ~1e-4 per row, which grows with the tank
    # mesh; exact solid angles for every pair cost ~1/3 more assembly (as PoseSweep's tank block)
    far = np.inf if not boundary.unbounded else FAR
    if n_c == 0:
        A, B = mixed_system(tris.centroids, tris, own, c_single, c_double, group, n, far=far)
        return BemSystem(A, -B, scale, z_c, 0)
    A, B = mixed_system(tris.centroids, tris, own, c_single, c_double, group, n + n_c, far=far)
    M = np.zeros((n_f + n_c, n_f + n_c))
    M[:n_f, :n_f] = A
    M[:n_f, n_f:] = B[:, n:]
    mean_area = float(np.mean(tris.areas))
    for c in range(n_c):
        on = boundary.conductor == c
        if not on.any():
            raise BoundaryError(f"conducting object {boundary.conductor_names[c]} has no faces")
        M[n_f + c, :n_f][on] = tris.areas[on] / mean_area
    rhs = np.zeros((n_f + n_c, n))
    rhs[:n_f] = -B[:, :n]
    return BemSystem(M, rhs, scale, z_c, n_c)
