"""Axisymmetric reduction for a sensor of revolution alone in unbounded water.

A sensor meshed by :func:`electrosense.meshes.sensor_mesh.mesh_sensor` is a stack of
bands between rings of vertices. In unbounded water every electrode
potential pattern is axisymmetric, and so is the solution: on each band the
triangles pointing up (two vertices on the upper ring) share one value and
those pointing down another, up to the mesh's small departures from
rotational symmetry. With one unknown per (band, orientation) class, the
system is a Petrov-Galerkin projection of the collocation system:

* columns summed per class (:func:`electrosense.bem.operators.mixed_system_reduced`),
* rows averaged per class with area weights, collocating at up to
  ``targets_per_class`` triangles of each class (spread around the ring).

The matrix is (number of classes)^2, a few hundred, so the cost is the
assembly of ``targets x triangles`` pairs and no dense factorisation: about
5-10 x faster than the full collocation for angels-4 with every triangle
as a collocation point, and within 1e-4 of it (tests/test_bem_api.py).

Example
-------
>>> from electrosense.meshes import preset
>>> from electrosense.meshes.sensor_mesh import mesh_sensor
>>> from electrosense.bem.boundary_conditions import WaterBoundary
>>> wb = WaterBoundary.from_meshes(mesh_sensor(preset("angels-2")))
>>> cls, n = ring_classes(wb)
>>> bool(n < wb.n_triangles / 10)
True
"""
from __future__ import annotations

import time

import numpy as np

from electrosense.bem.boundary_conditions import WaterBoundary
from electrosense.bem.conductance import check_conductivity
from electrosense.bem.linear_solve import SingularSystemError
from electrosense.bem.operators import mixed_system_reduced
from electrosense.bem.solution import unit_solutions
from electrosense.bem.system import BemSystem, boundary_columns

#: collocation points per ring class in :func:`electrosense.bem.solve.solve_scene`: K within 6e-6 of all of them (angels-4)
AXISYMMETRIC_TARGETS_PER_CLASS = 16

__all__ = ["ring_classes", "is_axisymmetric_sensor", "solve_axisymmetric"]


def ring_classes(boundary: WaterBoundary):
    """(class per face, number of classes): band between two rings x orientation."""
    x = boundary.triangles_m[:, :, 0]
    top = x.max(axis=1, keepdims=True)
    scale = max(np.ptp(x), 1e-300)
    key = np.column_stack([np.round(x.min(axis=1) / scale * 1e9), np.round(top[:, 0] / scale * 1e9),
                           (np.abs(x - top) < 1e-9 * scale).sum(axis=1), boundary.electrode])
    _, cls = np.unique(key.astype(np.int64), axis=0, return_inverse=True)
    cls = cls.ravel()
    return cls, int(cls.max()) + 1


def is_axisymmetric_sensor(boundary: WaterBoundary, tol: float = 1e-9) -> bool:
    """True for a lone sensor in unbounded water whose vertices all lie on rings about the x axis
    (its own frame: a sensor turned off the x axis is not recognised)."""
    if not boundary.unbounded or boundary.n_conductors or len(boundary.part_names) != 1:
        return False
    v = boundary.triangles_m.reshape(-1, 3)
    scale = np.ptp(v[:, 0])
    r = np.hypot(v[:, 1], v[:, 2])
    key = np.round(v[:, 0] / scale * 1e9).astype(np.int64)
    order = np.argsort(key, kind="stable")
    k, rr = key[order], r[order]
    starts = np.flatnonzero(np.r_[True, k[1:] != k[:-1]])
    lo = np.minimum.reduceat(rr, starts)
    hi = np.maximum.reduceat(rr, starts)
    # each ring: at least three vertices (a mesh turned off the x axis has one per "ring"), all radii
    # equal within the ring (vertex radii may differ between rings)
    if np.any(np.diff(np.r_[starts, len(k)]) < 3):
        return False
    return bool(np.all(hi - lo <= tol * scale + 1e-3 * hi))


def solve_axisymmetric(boundary: WaterBoundary, sigma_S_per_m: float, contact_impedance_ohm_m2=None,
                       emitter: int | None = None, targets_per_class: int | None = None):
    """The BEM solution by the axisymmetric reduction (a :class:`electrosense.bem.solution.BemSolution`).

    ``targets_per_class``: collocate at that many triangles of each class
    (``None``: all of them, the area-weighted average of the full collocation
    equations; 4 is three times faster and within about 3e-4).
    """

    t0 = time.perf_counter()
    sigma_S_per_m = check_conductivity(sigma_S_per_m)
    n = boundary.n_electrodes
    emitter = n if emitter is None else int(emitter)
    tris, z_c, scale, c_single, c_double, group = boundary_columns(boundary, sigma_S_per_m, contact_impedance_ohm_m2)
    cls, n_cls = ring_classes(boundary)
    # collocation targets: up to targets_per_class faces of each class, spread over the class
    targets = []
    for members in np.split(np.argsort(cls, kind="stable"), np.cumsum(np.bincount(cls))[:-1]):
        if targets_per_class is None or targets_per_class >= len(members):
            targets.append(members)
            continue
        pick = np.unique(np.linspace(0, len(members) - 1, targets_per_class).round().astype(int))
        targets.append(members[pick])
    targets = np.concatenate(targets)
    A, B = mixed_system_reduced(tris.centroids[targets], tris, targets, c_single, c_double, group, n, cls, n_cls)
    import scipy.sparse

    average = scipy.sparse.csr_matrix((tris.areas[targets], (cls[targets], np.arange(len(targets)))),
                                      shape=(n_cls, len(targets)))
    Ar = average @ A
    br = -(average @ B)
    t1 = time.perf_counter()
    try:
        y = np.linalg.solve(Ar, br)
    except np.linalg.LinAlgError:
        raise SingularSystemError("the axisymmetric BEM system is singular") from None
    x = y[cls]
    t2 = time.perf_counter()
    system = BemSystem(matrix=None, rhs=None, scale_m=scale, z_c=z_c, n_conductors=0)
    solution = unit_solutions(boundary, sigma_S_per_m, system, x, emitter,
                       {"assembly_s": t1 - t0, "solve_s": t2 - t1, "method": "axisymmetric reduction",
                        "axisymmetric_classes": n_cls,
                        "collocation_points": int(len(targets))})
    return solution
