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
since the meridian is one-dimensional and graded to 1e-7 m). Carried into any
scene with that sensor and that mesh (in a tank, near a wall, with objects) by
:func:`scaled_to_scene` (each pair's correction scaled by the scene's change of
that pair's conductance: the charge the mesh misses at an edge follows the
charge there), it removes the edge error and leaves the error of the scene's
own correction ``K_scene - K_unbounded`` (walls and objects), which is a few
percent of K and converges fast: a defect correction, as in multi-fidelity
schemes. Added as a constant instead, it would leave about its own size times
the scene's relative change of K (a tip 5 mm from a wall: 0.06 % of K, against
0.015 % scaled, measured against the wall's exact image on ring elements).

Sectors. A sensor whose electrodes are split into sectors
(:mod:`electrosense.meshes.sensor`) has no axisymmetric solution, and the ring elements
cannot describe it. Its axial edges (where a sector meets the insulator along
the axis) carry the same singularity as a whole ring's, spread along the
sector's arc, so its correction is the whole sensor's (every electrode whole,
:meth:`~electrosense.meshes.sensor.SensorDescription.merged`), on the sector mesh with its
sectors and gaps relabelled as the whole electrode (:func:`merged_mesh`: the
same rings, an axisymmetric problem), shared out by arc: ``dK[i, j] = f_i f_j dK_whole[a, b]`` for sector ``i`` of electrode
``a`` and ``j`` of ``b``, ``f`` the sector's share of the circumference (1 for
a whole electrode), then made to have zero row sums. With no gap the sectors'
shares add up to 1, and the sectors driven together get exactly the whole
electrode's correction. The sector edges' own error (across the gaps, order
~1 in the spacing there, ~1 % of a sector's K at the default mesh) is removed
by Richardson extrapolation against a companion mesh whose sector-edge
spacings are twice as coarse (:func:`sector_edge_correction`).

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
from electrosense.bem.block_cache import BlockCache, cache_root, source_digest
from electrosense.bem.boundary_conditions import WaterBoundary
from electrosense.bem.meridian import meridian_conductance, mesh_meridian
from electrosense.bem.solution import solve

__all__ = ["free_space_correction", "scene_correction", "scaled_to_scene",
           "free_space_correction_with_K", "clear_cache", "MERIDIAN_GRADING", "sector_shares", "merged_mesh",
           "sector_edge_correction"]

#: grading of the meridian used for the correction (angels-4: 970 elements, 1.2e-4 of converged, 0.3-0.6 s)
MERIDIAN_GRADING = 1.15


def free_space_correction(sensor, sigma_S_per_m: float, contact_impedance_ohm_m2, sensor_mesh,
                          targets_per_class: int | None = None, surface_K_S=None,
                          mesh_options: dict | None = None, disk_cache: bool = True) -> np.ndarray:
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
    mesh_options : dict, optional
        For a sensor with sectors: the options of :func:`electrosense.meshes.sensor_mesh.mesh_sensor` that made
        ``sensor_mesh`` (``edge_length_m`` among them), from which the companion mesh of the sector-edge
        term is made.
    disk_cache : bool
        Keep the correction on disk for later processes (the ``edge-corrections`` folder of the cache root,
        keyed by the inputs and the sources of :mod:`electrosense.bem` and :mod:`electrosense.meshes`).
    """
    return free_space_correction_with_K(sensor, sigma_S_per_m, contact_impedance_ohm_m2, sensor_mesh,
                                        targets_per_class, surface_K_S, mesh_options, disk_cache)[0]


def scene_correction(sensor, sigma_S_per_m: float, contact_impedance_ohm_m2, sensor_mesh, scene_K_S,
                     targets_per_class: int | None = None, surface_K_S=None, mesh_options: dict | None = None,
                     disk_cache: bool = True) -> np.ndarray:
    """The edge correction of a scene (tank, walls, objects) whose surface BEM gave ``scene_K_S`` with this
    sensor mesh: :func:`free_space_correction` carried into the scene by :func:`scaled_to_scene`.

    Parameters as :func:`free_space_correction`, and ``scene_K_S`` (n, n), the scene's K of the surface solution
    (without correction). In unbounded water it returns :func:`free_space_correction` itself.
    """
    dK, free_K = free_space_correction_with_K(sensor, sigma_S_per_m, contact_impedance_ohm_m2, sensor_mesh,
                                        targets_per_class, surface_K_S, mesh_options, disk_cache)
    return scaled_to_scene(dK, free_K, scene_K_S)


def scaled_to_scene(dK_free_S, free_K_S, scene_K_S) -> np.ndarray:
    """The free-space correction ``dK_free_S`` of a mesh whose free-space K is ``free_K_S``, carried into a scene
    where the same mesh gives ``scene_K_S``: each mutual conductance's correction scaled by the scene's change of
    it, the diagonal from zero row sums.

    ``dK[i, j] = dK_free[i, j] * K_scene[i, j] / K_free[i, j]`` (i != j). The mesh's error is the singular charge
    it misses at the electrode edges; the singularity's strength there is set by the field the scene drives
    through that edge, so the missing charge follows the charge itself (first order in the mesh's error). A wall
    or an object that changes the pair's conductance by 18 % changes its correction by as much, which a constant
    correction misses: a sensor's tip 5 mm from a wall, square on (exact by ring elements and the wall's image,
    :func:`electrosense.bem.meridian.layer_operators`), leaves the constant correction 0.06 % of max|K| from the
    converged K, this one 0.015 %, no more than in free space (0.010 %; ``esense study edge_correction_wall``).
    Pairs whose free-space conductance is below 1e-9 of the largest keep the constant correction.

    Example
    -------
    >>> dK = np.array([[1.0, -1.0], [-1.0, 1.0]]) * 1e-5
    >>> K = np.array([[1.0, -1.0], [-1.0, 1.0]]) * 1e-2
    >>> scaled_to_scene(dK, K, 1.2 * K).round(8).tolist()      # the scene's K 20 % larger: so is the correction
    [[1.2e-05, -1.2e-05], [-1.2e-05, 1.2e-05]]
    """
    dK, free_K, scene_K = (np.asarray(a, float) for a in (dK_free_S, free_K_S, scene_K_S))
    tiny = np.abs(free_K) <= 1e-9 * np.abs(free_K).max()
    ratio = np.where(tiny, 1.0, scene_K / np.where(tiny, 1.0, free_K))
    scaled = dK * ratio
    np.fill_diagonal(scaled, 0.0)
    scaled = 0.5 * (scaled + scaled.T)
    return scaled - np.diag(scaled.sum(axis=1))


def free_space_correction_with_K(sensor, sigma_S_per_m: float, contact_impedance_ohm_m2, sensor_mesh,
                                 targets_per_class: int | None = None, surface_K_S=None,
                                 mesh_options: dict | None = None,
                                 disk_cache: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """``(dK, K_free)``: :func:`free_space_correction` and the mesh's own free-space K it was measured against
    (copies; both kept in the same caches), which :func:`scaled_to_scene` needs to carry it into a scene."""
    if sensor.has_sectors:
        return _sector_correction(sensor, sigma_S_per_m, contact_impedance_ohm_m2, sensor_mesh, targets_per_class,
                                  surface_K_S, mesh_options or {})
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
        compute = lambda: _correction(sensor, float(sigma_S_per_m), z, sensor_mesh, tpc, surface_K_S)  # noqa: E731
        arrays = (sensor_mesh.vertices_m, sensor_mesh.faces, sensor_mesh.electrode,
                  np.array([float(sigma_S_per_m), tpc]), np.asarray([] if z is None else z, float).ravel(),
                  np.frombuffer(repr(sensor).encode(), np.uint8), np.frombuffer(source_digest().encode(), np.uint8))
        _CACHE[key] = _stored(arrays, compute) if disk_cache else compute()
    return tuple(a.copy() for a in _CACHE[key])


def _stored(arrays, compute) -> tuple[np.ndarray, np.ndarray]:
    """The correction and the mesh's free-space K stored on disk under the hash of ``arrays`` (the
    ``edge-corrections`` folder of the cache root), else ``compute()``, stored: a later process with the same
    sensor mesh, conductivity and contact impedance reads them back instead of solving the refined meridian
    problem again (seconds)."""
    cache = BlockCache(cache_root() / "edge-corrections")
    key = cache.key(*arrays)
    found = cache.load(key, ("dK_S", "K_surface_S"))
    if found is not None:
        return found[0], found[1]
    dK, surface = (np.asarray(a, float) for a in compute())
    cache.save(key, {"dK_S": dK, "K_surface_S": surface})
    return dK, surface


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


def merged_mesh(sensor, sector_mesh):
    """The sector mesh with every electrode whole again: each split electrode's sectors and the gaps between them
    labelled as the whole electrode (numbered as in :meth:`~electrosense.meshes.sensor.SensorDescription.merged`)."""
    x = sector_mesh.triangles_m[:, :, 0].mean(axis=1)
    label = np.zeros(sector_mesh.n_triangles, np.int64)
    on = sector_mesh.electrode > 0
    number_to_index = np.array([0] + [sensor.sector_of(k)[0] + 1 for k in range(1, sensor.n_electrodes + 1)])
    label[on] = number_to_index[sector_mesh.electrode[on]]
    for j, e in enumerate(sensor.electrodes, start=1):   # the gaps of a split electrode
        if e.is_split:
            band = (sector_mesh.electrode == 0) & (x >= e.x_min_m) & (x <= e.x_max_m)
            label[band] = j
    from electrosense.meshes.labelled_mesh import LabelledMesh

    return LabelledMesh(sector_mesh.vertices_m, sector_mesh.faces, label, sector_mesh.region,
                        sector_mesh.region_names)


def _sector_correction(sensor, sigma, z, sensor_mesh, targets_per_class, surface_K_S, mesh_options):
    z_key = z if z is None or np.ndim(z) == 0 else tuple(np.asarray(z, float).tolist())
    digest = hashlib.sha1(np.ascontiguousarray(sensor_mesh.vertices_m).tobytes()
                          + np.ascontiguousarray(sensor_mesh.faces).tobytes()
                          + np.ascontiguousarray(sensor_mesh.electrode).tobytes()).hexdigest()
    key = ("sectors", sensor, float(sigma), z_key, digest, tuple(sorted(mesh_options.items())))
    if key in _CACHE:
        return tuple(a.copy() for a in _CACHE[key])
    whole = sensor.merged()
    z_whole = z
    if z is not None and np.ndim(z) > 0:   # one value per sector: the mean of each electrode's sectors
        W = sensor.merge_matrix()
        z_whole = (np.asarray(z, float) @ W) / W.sum(axis=0)
    # the sector mesh's own edge error along the axis: its rings are those of a whole sensor's mesh
    dK_whole = free_space_correction(whole, sigma, z_whole, merged_mesh(sensor, sensor_mesh), targets_per_class)
    F = sector_shares(sensor)
    dK = F @ dK_whole @ F.T
    dK = dK - np.diag(dK.sum(axis=1))   # zero row sums (with gaps the shares add up to less than 1)
    surface = (_symmetric_surface_K(sensor, sigma, z, sensor_mesh) if surface_K_S is None
               else np.asarray(surface_K_S, float))
    dK = dK + sector_edge_correction(sensor, sigma, z, sensor_mesh, mesh_options, surface)
    if len(_CACHE) >= 32:
        _CACHE.pop(next(iter(_CACHE)))
    _CACHE[key] = (dK, surface)
    return dK.copy(), surface.copy()


def _symmetric_surface_K(sensor, sigma, z, mesh) -> np.ndarray:
    """A sector sensor's mesh alone in unbounded water: its K by :func:`electrosense.bem.symmetric.solve_symmetric`."""
    from electrosense.bem.symmetric import solve_symmetric
    from electrosense.meshes.sector_mesh import block_symmetry

    order, mirror = block_symmetry(sensor)
    wb = WaterBoundary.from_meshes(mesh, emitter=sensor.emitter, allow_touching=sensor.sectors_touch)
    z_list = z if z is None or np.ndim(z) == 0 else list(z)
    return solve_symmetric(wb, sigma, z_list, sensor.emitter, order=order, mirror=mirror).K_S


#: observed order of the sector-edge error in the sector-edge spacing (``validation/studies/sector_sensor.py``)
SECTOR_EDGE_ORDER = 1.0


def sector_edge_correction(sensor, sigma, z, sensor_mesh, mesh_options: dict, surface_K_S=None) -> np.ndarray:
    """The error of the sector edges (across the gaps) by Richardson extrapolation against a companion mesh.

    The companion is the same mesh with the spacings graded towards the sector
    edges twice as coarse (``sector_refinement / 2``, ``sector_grading - 1``
    doubled; the rings, and so the axial edges, unchanged). With the error of
    order :data:`SECTOR_EDGE_ORDER` in that spacing, the limit is
    ``K + (K - K_companion) / (2^p - 1)``; returns that term (S, zero row sums),
    less its part in the sums over the sectors of any electrode that has no
    sector edge to the insulator (whole, or split with no gap): there the two
    meshes differ by noise only, and the whole electrode's K stays that of
    the axial correction.
    Both K are free-space surface solutions, by :func:`electrosense.bem.symmetric.solve_symmetric`.
    Returns zeros when ``sensor_mesh`` is not what ``mesh_options`` make (a mesh of the caller's own).
    """
    from electrosense.meshes.sector_mesh import DEFAULT_SECTOR_GRADING, DEFAULT_SECTOR_REFINEMENT
    from electrosense.meshes.sensor_mesh import mesh_sensor

    options = dict(mesh_options)
    if not np.array_equal(mesh_sensor(sensor, **options).faces, sensor_mesh.faces):
        return np.zeros((sensor.n_electrodes, sensor.n_electrodes))
    refinement = options.pop("sector_refinement", DEFAULT_SECTOR_REFINEMENT)
    grading = options.pop("sector_grading", DEFAULT_SECTOR_GRADING)
    companion = mesh_sensor(sensor, sector_refinement=max(1.0, refinement / 2), sector_grading=1 + 2 * (grading - 1),
                            **options)
    K = (_symmetric_surface_K(sensor, sigma, z, sensor_mesh) if surface_K_S is None
         else np.asarray(surface_K_S, float))
    dK = (K - _symmetric_surface_K(sensor, sigma, z, companion)) / (2.0 ** SECTOR_EDGE_ORDER - 1.0)
    dK = 0.5 * (dK + dK.T)
    dK = dK - np.diag(dK.sum(axis=1))
    # an electrode with no sector edge to the insulator (whole, or split with no gap) has no such error: what
    # the two meshes give its sectors together differs by the meshes' noise only. Take it out, shared by arc.
    W = sensor.merge_matrix()
    F = sector_shares(sensor)
    F = F / (W.T @ F).diagonal()[None, :]
    plain = np.array([not e.is_split or e.sector_gap_m == 0 for e in sensor.electrodes])
    mask = plain[:, None] | plain[None, :]
    dK = dK - F @ ((W.T @ dK @ W) * mask) @ F.T
    return dK - np.diag(dK.sum(axis=1))


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
    return dK - np.diag(dK.sum(axis=1)), surface   # exact zero row sums (both are zero to rounding)
