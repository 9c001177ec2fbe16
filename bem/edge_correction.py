"""Free-space discretisation correction of a sensor's conductance matrix (electrode-edge error).

The current density on an electrode is singular where it meets the
insulator (~ d^-1/2). A graded surface mesh of a few thousand triangles
resolves it to a few tenths of a percent, and converges slowly (observed
order ~1.2 in the edge length): the error of the surface BEM's conductance
matrix is almost entirely this edge error, local to the sensor and nearly the
same wherever the sensor is. The correction

    dK = K_meridian(sensor, unbounded) - K_surface(sensor mesh, unbounded)

is the surface mesh's own error in unbounded water, measured against the
ring-element BEM of :mod:`electrosense.bem.meridian` (converged to ~1e-4 in a second,
since the meridian is one-dimensional and graded to 1e-7 m). Added to the
surface BEM's matrix of any scene with that sensor and that mesh (in a tank,
near a wall, with objects), it removes the edge error and leaves the error of
the scene's own correction ``K_scene - K_unbounded`` (walls and objects),
which is a few percent of K and converges fast: a defect correction, as in
multi-fidelity schemes.

Sectors. A sensor whose electrodes are split into sectors
(:mod:`electrosense.meshes.sensor`) has no axisymmetric solution, and the ring elements
cannot describe it. Its axial edges (where a sector meets the insulator along
the axis) carry the same singularity as a whole ring's, spread along the
sector's arc, so its correction is the whole sensor's (every electrode whole,
:meth:`~electrosense.meshes.sensor.SensorDescription.merged`, on its own mesh) shared out by
arc: ``dK[i, j] = f_i f_j dK_whole[a, b]`` for sector ``i`` of electrode
``a`` and ``j`` of ``b``, ``f`` the sector's share of the circumference (1 for
a whole electrode), then made to have zero row sums. With no gap the sectors'
shares add up to 1, and the sectors driven together get exactly the whole
electrode's correction. The sector edges' own error (across the gaps) is not
corrected: ``validation/studies/sector_sensor.py`` measures it by refinement.

``dK`` is symmetric with zero row sums (both matrices are), so ``K + dK``
keeps the conventions of :mod:`electrosense.bem.conductance`. It applies to the sensor's
conductance matrix only, not to the surface solution or the fields, and only
to sensors of revolution described by a :class:`electrosense.meshes.sensor.SensorDescription`
(a user's mesh file is solved as it is).

Example
-------
>>> from electrosense.meshes import preset
>>> from electrosense.meshes.sensor_mesh import mesh_sensor
>>> s = preset("angels-2")
>>> dK = free_space_correction(s, 1.0, None, mesh_sensor(s))
>>> bool(0.001 < dK[0, 0] / 0.0464 < 0.01)   # the default surface mesh is ~0.4 % low
True
"""
from __future__ import annotations

import hashlib

import numpy as np

from electrosense.bem.axisymmetric import AXISYMMETRIC_TARGETS_PER_CLASS, is_axisymmetric_sensor, solve_axisymmetric
from electrosense.bem.boundary_conditions import WaterBoundary
from electrosense.bem.meridian import meridian_conductance, mesh_meridian
from electrosense.bem.solution import solve

__all__ = ["free_space_correction", "clear_cache", "MERIDIAN_GRADING", "sector_shares"]

#: grading of the meridian used for the correction (angels-4: 970 elements, 1.2e-4 of converged, 0.3-0.6 s)
MERIDIAN_GRADING = 1.15


def free_space_correction(sensor, sigma_S_per_m: float, contact_impedance_ohm_m2, sensor_mesh,
                          targets_per_class: int | None = None, surface_K_S=None) -> np.ndarray:
    """``dK`` (n, n) in siemens: the converged free-space K minus the surface mesh's free-space K.

    Parameters
    ----------
    sensor : SensorDescription
    sigma_S_per_m : float
    contact_impedance_ohm_m2 : None, float or sequence (ohm m^2)
    sensor_mesh : LabelledMesh
        The sensor's surface mesh in its own frame (:func:`electrosense.meshes.sensor_mesh.mesh_sensor`),
        the one the scene is solved with.
    targets_per_class : int, optional
        Collocation points per ring class of the axisymmetric reduction
        (default: :data:`electrosense.bem.axisymmetric.AXISYMMETRIC_TARGETS_PER_CLASS`).
    surface_K_S : (n, n) array, optional
        The mesh's free-space K when the caller has just solved it (saves that solve).
    """
    if sensor.has_sectors:
        return _sector_correction(sensor, sigma_S_per_m, contact_impedance_ohm_m2, sensor_mesh, targets_per_class)
    z = contact_impedance_ohm_m2
    if z is not None:
        z = float(z) if np.ndim(z) == 0 else tuple(np.asarray(z, float).tolist())   # hashable, as given
    digest = hashlib.sha1(np.ascontiguousarray(sensor_mesh.vertices_m).tobytes()
                          + np.ascontiguousarray(sensor_mesh.faces).tobytes()
                          + np.ascontiguousarray(sensor_mesh.electrode).tobytes()).hexdigest()
    tpc = AXISYMMETRIC_TARGETS_PER_CLASS if targets_per_class is None else targets_per_class
    key = (sensor, float(sigma_S_per_m), z, digest, tpc)
    if key not in _CACHE:
        if len(_CACHE) >= 32:
            _CACHE.pop(next(iter(_CACHE)))
        _CACHE[key] = _correction(sensor, float(sigma_S_per_m), z, sensor_mesh, tpc, surface_K_S)
    return _CACHE[key].copy()


_CACHE: dict = {}


def clear_cache() -> None:
    """Forget the corrections computed in this process (they are kept per sensor, sigma, z_c and mesh)."""
    _CACHE.clear()


def sector_shares(sensor) -> np.ndarray:
    """(n_electrodes, len(electrodes)): each sector's share of its electrode's circumference (whole: 1).

    Example
    -------
    >>> from electrosense.meshes import preset
    >>> s = preset("angels-2").with_sectors({1: 4})
    >>> sector_shares(s)[:, 0].tolist()
    [0.25, 0.25, 0.25, 0.25, 0.0]
    """
    from electrosense.meshes.sensor import sector_azimuths_rad

    F = np.zeros((sensor.n_electrodes, len(sensor.electrodes)))
    for j, e in enumerate(sensor.electrodes):
        numbers = np.asarray(sensor.numbers_of(j)) - 1
        F[numbers, j] = 1.0 if not e.is_split else sector_azimuths_rad(e, sensor.radius_m)[1] / np.pi
    return F


def _sector_correction(sensor, sigma, z, sensor_mesh, targets_per_class):
    from electrosense.meshes.sensor_mesh import mesh_sensor

    whole = sensor.merged()
    z_whole = z
    if z is not None and np.ndim(z) > 0:   # one value per sector: the mean of each electrode's sectors
        W = sensor.merge_matrix()
        z_whole = (np.asarray(z, float) @ W) / W.sum(axis=0)
    dK_whole = free_space_correction(whole, sigma, z_whole, mesh_sensor(whole), targets_per_class)
    F = sector_shares(sensor)
    dK = F @ dK_whole @ F.T
    return dK - np.diag(dK.sum(axis=1))   # zero row sums (with gaps the shares add up to less than 1)


def _correction(sensor, sigma, z, sensor_mesh, targets_per_class, surface_K_S):
    if surface_K_S is not None:
        surface = np.asarray(surface_K_S, float)
    else:
        wb = WaterBoundary.from_meshes(sensor_mesh, emitter=sensor.emitter)
        z_list = z if np.ndim(z) == 0 else list(z)
        if is_axisymmetric_sensor(wb):
            surface = solve_axisymmetric(wb, sigma, z_list, sensor.emitter, targets_per_class=targets_per_class).K_S
        else:   # not ring by ring (not mesh_sensor's): the full collocation of the same mesh
            surface = solve(wb, sigma, z_list, sensor.emitter).K_S
    reference = meridian_conductance(sensor, sigma, z if np.ndim(z) == 0 else list(z),
                                     mesh=mesh_meridian(sensor, grading=MERIDIAN_GRADING)).K_S
    dK = reference - surface
    dK = 0.5 * (dK + dK.T)
    return dK - np.diag(dK.sum(axis=1))   # exact zero row sums (both are zero to rounding)
