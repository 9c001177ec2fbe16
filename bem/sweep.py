"""Many poses of one sensor in one tank, reusing everything that does not move.

Split the unknowns into the sensor's ``s`` (rigid: its own block ``A_ss`` is
the same in every pose, computed in the sensor frame) and the environment's
``e`` (tank walls, floor, free surface and objects, fixed in the tank frame:
``A_ee``). Only the coupling blocks ``A_se`` and ``A_es`` change with the pose::

    [A_ss  A_se] [y_s]   [r_s]
    [A_es  A_ee] [y_e] = [r_e]

The sensor's block is LU-factorised once, in float32, and kept on disk,
keyed by a hash of everything it depends on, so that the next process
reuses it (:mod:`electrosense.bem.block_cache`); ``y0 = A_ss^-1 r_s`` is computed once,
refined to float64 accuracy. Per pose, the coupling blocks are assembled
and the coupling ``A_se`` (sensor points x environment triangles: a smooth
kernel, numerically low rank) is compressed by a truncated SVD,
``A_se ~ U_k s_k V_k^T``. One triangular solve with the ``k`` columns
``W = A_ss^-1 U_k s_k`` (``k`` 33-55 for ``angels-4`` in the 1 m tank at the
default ``tol = 1e-6``, which moves K by 2e-8; 100-180 for a 5-electrode sensor
with a tip 1.5 cm from a wall, moving K by 2e-6 against ``tol = 1e-10``) gives the environment's Schur
complement exactly (up to the truncation)::

    (A_ee - A_es W V_k^T) y_e = r_e - A_es y0,      y_s = y0 - W V_k^T y_e,

a small dense system (environment unknowns only). The pose costs one pass
over the stored factors (O(k N_s^2)) against the O(N_s^3) of a fresh
factorisation. The full system is nonsingular, so the Schur complement is
too, also in a closed tank where ``A_ee`` alone is not.

Nor is the Schur complement factorised at each pose: it is ``A_ee`` less a
rank-``k`` term. ``A_ee`` is made nonsingular once by a rank-one term,
``A' = A_ee + c a b^T`` (constant vectors: in a closed tank the constant
potential is its null vector), and factorised once per sweep; each pose then
solves with the Sherman-Morrison-Woodbury formula (Golub & Van Loan,
*Matrix Computations*, 4th ed., 2.1.4)::

    (A' - U C)^-1 f = g + Z (I - C Z)^-1 C g,   g = A'^-1 f,  Z = A'^-1 U,
    U = [c a, A_es W],  C = [b^T; V_k^T],

at O(k N_e^2) instead of O(N_e^3) (``angels``-sized sensors in a tank of a
few thousand triangles: about three times faster per pose). Where ``A'`` is
too ill-conditioned for this to be safe (``rcond`` below
:data:`WOODBURY_MIN_RCOND`), the Schur complement is factorised per pose.
``A'`` is factorised in float32 and each pose's solution refined on float64
residuals of the Schur complement (``A_e y - (A_es W) V_k^T y``, one
product with ``A_e`` a step), as the sensor's block: a tank mesh graded to
one pose near a wall (4 400 triangles) factorised in 0.3 s against 0.6 s.

The tank mesh is graded towards the whole trajectory (the sensor's axis at
every pose of the first batch, or ``focus_m``), so that one tank mesh serves
every pose. ``PoseSweep`` holds only numpy arrays: it pickles, and its
pose-invariant state can be scattered to workers.

Example
-------
>>> import numpy as np
>>> from electrosense.meshes import Tank, preset
>>> from electrosense.bem.sweep import PoseSweep
>>> sweep = PoseSweep(preset("angels-2"), Tank((1.0, 1.0, 1.0)), sigma_S_per_m=0.0354)   # doctest: +SKIP
>>> g = sweep.conductance(np.array([[0.0, 0, 0, 0], [0.2, 0, 0, 0]]))                   # doctest: +SKIP
>>> g.K_S.shape                                                                         # doctest: +SKIP
(2, 2, 2)
"""
from __future__ import annotations

import copy
import time

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from electrosense.bem.axisymmetric import AXISYMMETRIC_TARGETS_PER_CLASS, is_axisymmetric_sensor, solve_axisymmetric
from electrosense.bem.boundary_conditions import WaterBoundary
from electrosense.bem.conductance import ConductanceMatrix, check_conductivity, isolate
from electrosense.bem.cross_approximation import cross_approximation, recompressed
from electrosense.bem.edge_correction import free_space_correction_with_K, scaled_to_scene
from electrosense.bem.image_plane import split_image_faces
from electrosense.bem.linear_solve import SingularSystemError, factorise, refine, solve_refined
from electrosense.bem.low_rank import right_singular_vectors
from electrosense.bem.memory import check_bytes, check_memory
from electrosense.bem.operators import TriangleSet, mixed_entries, mixed_system, mixed_system_reduced
from electrosense.bem.shape_derivative import layer_part, shape_derivatives, surface_gradient_operator
from electrosense.bem.solution import solve
from electrosense.bem.solve import check_object_materials
from electrosense.bem.system import column_coefficients, contact_impedances
from electrosense.meshes.pose import Pose, poses_array, rotation_z
from electrosense.meshes.scene_mesh import DEFAULT_TANK_GRADING, DEFAULT_TANK_NEAR_RATIO

__all__ = ["PoseSweep", "pose_bytes", "WOODBURY_MIN_RCOND", "LOW_PRECISION_MIN_RCOND", "WALL_SPLIT_RADIUS_FACTOR"]

#: wall derivatives: the tank's faces within this many sensor lengths of the sensor's axis take the sensor's part
#: of their potential exactly (:mod:`electrosense.bem.shape_derivative`)
WALL_SPLIT_RADIUS_FACTOR = 0.6

#: the sensor's own image (:meth:`PoseSweep._sensor_block_at`) is truncated at this times ``tol``: at ``tol``
#: itself it moved K by 1.8e-5 where the coupling's truncation moves it by 6e-6 (angels-4 parallel to the 1 m
#: tank's wall 5 mm from it, ``tol = 1e-5``)
IMAGE_TOL_FACTOR = 0.1

#: the sensor's own image is cross-approximated (:meth:`PoseSweep._sensor_image_low_rank`) on a sensor mesh of
#: at least this many triangles (on fewer its assembly costs less than the approximation), to this factor times
#: its truncation in the Frobenius norm (the block's singular values fall slowly past the truncation: rank 52 at
#: 1e-5 of the largest and 84 at 1e-5 of the Frobenius norm, 117 and 217 at 1e-6; a random 4-electrode sensor of
#: 1 944 triangles at a corner of the tank), where that is at least ``IMAGE_CROSS_MIN_TOL``: the tank map's poses
#: (``tol`` 1e-5, the Frobenius 1e-5: ranks 133-185 of 8 242 triangles 5-12 mm from a wall, K within 5e-6 of
#: the assembled images' and a pose 1.6-1.8x faster), not the BEM's default (``tol`` 1e-6: past N / 4 terms at a
#: corner with the floor 3 cm below, and the assembly pays)
IMAGE_CROSS_MIN_TRIANGLES, IMAGE_CROSS_TOL_FACTOR, IMAGE_CROSS_MIN_TOL = 4000, 10.0, 1e-5

#: the sensor-tank coupling (:meth:`PoseSweep._coupling_low_rank`) is cross-approximated on a sensor mesh of at
#: least this many triangles where ``tol`` is at least ``IMAGE_CROSS_MIN_TOL`` and the scene has no object (a tank
#: map's poses, whose meshed faces are at least ``image_faces_within_m`` from the sensor: smooth kernels), the
#: sensor's rows to this factor times ``tol`` in the Frobenius norm, the tank's rows (its block and right-hand
#: side) to the second factor times it. The sensor's rows carry a flat tail of singular values (the quadrature
#: switching its rule between a graded tank's triangles): ranks 53-55 at ``tol`` of the largest, 337 to ``tol`` of
#: the Frobenius norm, 77-133 to 3x it, 53 to 10x it (a random 5-electrode sensor's coarse mesh, 2 548 triangles,
#: in its map's poses); at 3x the receiver currents moved by 4e-6 RMS, 1e-5 at most over 12 poses, and a pose
#: cost 18 % less CPU (10x: 28 % less, 3e-5 at most); a random 4-electrode sensor's coarse mesh of 1 944
#: triangles, 11 % less, 4e-6 RMS, 9e-6 at most. On the first's 10 916-triangle reference mesh the sensor's rows
#: needed rank 578 at 3x: not worth it (the tally below gives up)
COUPLING_CROSS_MIN_TRIANGLES, COUPLING_CROSS_TOL_FACTOR, COUPLING_RHS_CROSS_TOL_FACTOR = 1000, 3.0, 1.0

#: smallest reciprocal condition number of the regularised environment block ``A'`` for which poses are solved by
#: the Woodbury formula (below it, the Schur complement is factorised at each pose)
WOODBURY_MIN_RCOND = 1e-8

#: smallest reciprocal condition number of the float32 factors of ``A'`` for which a pose is solved with them and
#: refined (as :func:`electrosense.bem.linear_solve.solve_dense`); below it the factors are float64
LOW_PRECISION_MIN_RCOND = 1e-6

#: relative residual of a pose's environment solve at which its refinement stops, and the most refinements
REFINEMENT_TOL, MAX_REFINEMENTS = 1e-12, 8


def pose_bytes(n_sensor: int, n_environment: int) -> float:
    """Bytes a sweep holds while it solves a pose, ``n_sensor`` and ``n_environment`` (tank and objects)
    triangles: the sensor block's float32 factors, the environment's block ``A_e`` and ``A' = A_e + c a b^T``
    factorised in place with the assembly's scratch (2.5 matrices: a 36 000-triangle tank passed at 1.3 and used
    12 GB), and the pose's coupling blocks (``A_se``, ``A_es``, ``A_se`` in float32, the range finder's products).

    >>> round(pose_bytes(2000, 1000) / 1e9, 3)
    0.084
    """
    Ns, Ne = float(n_sensor), float(n_environment)
    return 4.0 * Ns**2 + 8.0 * (2.5 * Ne**2 + 3.0 * Ns * Ne)


def _image_faces(image_face, tank) -> tuple:
    """``image_face`` (None, a face's name or several) as a tuple of names; refused in unbounded water."""
    faces = () if image_face is None else (image_face,) if isinstance(image_face, str) else tuple(image_face)
    if faces and tank is None:
        raise ValueError(f"image_face {', '.join(faces)}: unbounded water has no faces")
    return faces


def _pose_velocities(op, normals: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """(3, F) outward normal velocities of the tank's faces, as the sensor sees them, per metre of its x and y
    and per radian of its yaw (a turn about the vertical through its centre): the walls move the other way."""
    r = op.centroids_m - np.asarray(pose[:3], float)
    turn = np.column_stack([-r[:, 1], r[:, 0], np.zeros(len(r))])  # z x r
    return -np.stack([normals[:, 0], normals[:, 1], np.einsum("fk,fk->f", turn, normals)])


class PoseSweep:
    """Conductance matrices of one sensor at many poses in one tank (with fixed objects).

    Parameters
    ----------
    sensor : SensorDescription
    tank : Tank or None
        ``None``: unbounded water (then, without objects, K is pose independent).
    objects : tuple of scene objects (tank frame), insulating or conducting.
    sigma_S_per_m : float
    contact_impedance_ohm_m2 : float or (n,) sequence, optional
    edge_length_m : float, optional
        Sensor mesh edge length (default: the mesher's).
    tank_edge_length_m : float, optional
        Tank edge length nearest the trajectory (default: the scene mesher's).
    tank_grading : float, optional
        Growth of the tank's edge length per metre from the trajectory
        (default: the scene mesher's, :data:`electrosense.meshes.scene_mesh.DEFAULT_TANK_GRADING`).
    focus_m : (P, 3) array, optional
        Tank-frame points the tank mesh is graded towards; default: the
        sensor's axis at every pose of the first call.
    tank_near_ratio : float or None, optional
        The tank's edge at most this times its distance from the sensor's
        surface around ``focus_m`` (a focus on the sensor's axis); default
        :data:`electrosense.meshes.scene_mesh.DEFAULT_TANK_NEAR_RATIO`; None:
        no such bound (a focus spread over a whole plane of poses, where that
        bound would refine every wall).
    tol : float
        Relative truncation of the coupling's SVD (singular values below
        ``tol`` times the largest are dropped; randomised range finding,
        :mod:`electrosense.bem.low_rank`). ``angels-2`` in the 1 m tank, tip 1 cm from a
        wall: K within 1e-8 of the solution at 1e-10.
    block_cache : bool, str, Path or None
        Keep the sensor block's LU factors on disk and reuse them in later
        processes (:mod:`electrosense.bem.block_cache`): ``True`` in the user's cache
        directory, a directory, ``False`` never; ``None`` (default): only
        when the sensor mesh has at least ``CACHE_MIN_TRIANGLES`` triangles
        (where factorising costs more than reading).
    edge_correction : bool
        Correct every pose's K for the sensor mesh's electrode-edge error: the free-space correction
        (:mod:`electrosense.bem.edge_correction`; a few seconds, computed once per sensor mesh, conductivity
        and contact impedance, and kept on disk beside the sensor blocks) carried into the pose's scene by
        :func:`~electrosense.bem.edge_correction.scaled_to_scene`. The wall derivatives (``wall_derivatives``)
        are the surface solution's: the correction's own change with a wall is its size (0.5 %) times theirs.
    tank_mesh : LabelledMesh, optional
        The tank's mesh, made by the caller (e.g. a mesh of ``tank`` deformed
        smoothly, to difference K between shapes without remeshing); default:
        meshed here, graded towards ``focus_m``.
    cache_environment : bool
        Keep the tank's (and fixed objects') factors on disk too, where ``block_cache`` allows a disk cache
        of a block that size: for a tank mesh that later processes solve again (the diagnosis's anchors),
        not for one-off scenes (about 0.13 GB for 4 000 triangles).
    memory_share : float
        The fraction of this machine's available memory the sweep's blocks may take before it refuses the scene
        (:class:`~electrosense.bem.memory.MemoryRefusal`, naming its size): 1 alone, ``1 / k`` where ``k``
        sweeps hold their blocks at once (a tank map's workers).
    image_face : str or tuple of str, optional
        A flat face of the tank (a box's ``"wall_x-"`` ... ``"free_surface"``, a cylinder's ``"floor"`` or
        ``"free_surface"``), or several mutually perpendicular ones, taken into the Green's function by their
        images instead of a mesh (:mod:`electrosense.bem.image_plane`): the same K, exactly so in the
        continuum, without the mesh's error beside the sensor (``esense study image_plane``: angels-4 5 mm
        from a wall, 9.3 s of CPU against 13.4 s, the default mesh 0.039 % off; beyond 2 cm the sensor's own
        image, 4-6 s, makes it dearer than the mesh). Not with ``wall_derivatives``.

    Example
    -------
    See the module docstring.
    """

    def __init__(self, sensor, tank=None, objects=(), sigma_S_per_m: float = 1.0, contact_impedance_ohm_m2=None,
                 edge_length_m=None, tank_edge_length_m=None, focus_m=None, tol: float = 1e-6, block_cache=None,
                 edge_correction: bool = True, tank_grading: float | None = None, tank_mesh=None,
                 cache_environment: bool = False, memory_share: float = 1.0,
                 tank_near_ratio: float | None = DEFAULT_TANK_NEAR_RATIO, image_face=None,
                 **sensor_mesh_options):
        from electrosense.meshes.sensor_mesh import mesh_sensor

        sigma_S_per_m = check_conductivity(sigma_S_per_m)

        check_object_materials(objects)
        self.sensor = sensor
        self.tank = tank
        self.objects = tuple(objects)
        self.sigma_S_per_m = float(sigma_S_per_m)
        self.contact_impedance_ohm_m2 = contact_impedance_ohm_m2
        self.tank_edge_length_m = tank_edge_length_m
        self._given_tank_mesh = tank_mesh
        self.tank_grading = DEFAULT_TANK_GRADING if tank_grading is None else float(tank_grading)
        self.tank_near_ratio = tank_near_ratio
        self.image_faces = _image_faces(image_face, tank)
        self.image_group = None
        self.focus_m = None if focus_m is None else np.asarray(focus_m, float).reshape(-1, 3)
        self.tol = float(tol)
        # the sensor's own image's cross approximations that converged and that did not, shared with every
        # with_focus copy (:meth:`_sensor_image_low_rank` stops trying on a sensor where they do not pay)
        self._image_cross_tally = {"converged": 0, "not": 0}
        self._coupling_cross_tally = {"converged": 0, "not": 0}   # the same for the coupling
        if not 0.0 < memory_share <= 1.0:
            raise ValueError(f"memory_share must be in (0, 1], got {memory_share}")
        self.memory_share = float(memory_share)
        self.block_cache = block_cache
        self.cache_environment = bool(cache_environment)
        self.sensor_mesh = mesh_sensor(sensor, edge_length_m=edge_length_m, **sensor_mesh_options)
        self.n = sensor.n_electrodes
        self.emitter = sensor.emitter
        self._touching = bool(getattr(sensor, "sectors_touch", False))
        self.z_c = contact_impedances(contact_impedance_ohm_m2, self.n)
        self._env_ready = False
        self.timings = {}
        self._free_K = None   # K alone in unbounded water, when that is the whole problem
        self._woodbury = None
        t0 = time.perf_counter()
        if tank is None and not self.objects:
            self._prepare_free()
        else:
            self._prepare_sensor()
        self.timings["sensor_block_s"] = time.perf_counter() - t0
        self._edge_correction = bool(edge_correction)
        self._mesh_options = dict(sensor_mesh_options, edge_length_m=edge_length_m)
        self._prepare_edge_correction()

    def _prepare_edge_correction(self):
        """The sensor mesh's free-space edge correction and its free-space K, which :func:`scaled_to_scene` carries
        into every pose's scene."""
        self._K_correction = np.zeros((self.n, self.n))
        self._K_free_surface = None
        if self._edge_correction:
            t0 = time.perf_counter()
            self._K_correction, self._K_free_surface = free_space_correction_with_K(
                self.sensor, self.sigma_S_per_m, self.contact_impedance_ohm_m2, self.sensor_mesh,
                surface_K_S=self._free_K, mesh_options=self._mesh_options, disk_cache=self.block_cache is not False)
            self.timings["edge_correction_s"] = time.perf_counter() - t0

    def _corrected(self, K_surface_S: np.ndarray) -> np.ndarray:
        """A pose's K with the edge correction carried into its scene (:func:`scaled_to_scene`)."""
        if self._K_free_surface is None:
            return K_surface_S
        return K_surface_S + scaled_to_scene(self._K_correction, self._K_free_surface, K_surface_S)

    def with_contact_impedance(self, contact_impedance_ohm_m2) -> "PoseSweep":
        """This sweep with another contact impedance on the electrodes (ohm m^2, one or one per electrode).

        The electrodes' condition enters only the sensor's own columns: the sensor block and the edge correction
        are made anew, the tank's and objects' blocks (mesh, assembly, factors) are shared with this sweep. The
        result is the sweep that the same arguments with ``contact_impedance_ohm_m2`` would build on this sweep's
        tank mesh.

        >>> from electrosense.meshes import Tank, preset
        >>> sweep = PoseSweep(preset("angels-2"), Tank((0.4, 0.3, 0.3)), edge_length_m=0.01)
        >>> pose = [[0.05, 0.0, 0.0, 0.0]]
        >>> K0 = sweep.conductance(pose).K_S
        >>> K1 = sweep.with_contact_impedance(1e-3).conductance(pose).K_S
        >>> bool(abs(K1[0, 0, 0]) < abs(K0[0, 0, 0]))      # a contact impedance in series: less current
        True
        """
        if self.tank is None and not self.objects:      # no tank blocks to share
            return PoseSweep(self.sensor, None, (), self.sigma_S_per_m, contact_impedance_ohm_m2,
                             tol=self.tol, block_cache=self.block_cache, edge_correction=self._edge_correction,
                             **self._mesh_options)
        if not self._env_ready and (self.focus_m is not None or self._given_tank_mesh is not None):
            self._prepare_environment(np.zeros((0, 4)))    # once here, then shared by every copy
        new = copy.copy(self)
        # one trial impedance among many: its sensor block is not worth a disk entry unless the caller asked
        new.block_cache = False if self.block_cache is None else self.block_cache
        new.contact_impedance_ohm_m2 = contact_impedance_ohm_m2
        new.z_c = contact_impedances(contact_impedance_ohm_m2, self.n)
        new.timings = {}
        t0 = time.perf_counter()
        new._prepare_sensor()
        new.timings["sensor_block_s"] = time.perf_counter() - t0
        new._prepare_edge_correction()
        return new

    def with_focus(self, focus_m=None, tank_near_ratio: float | None = DEFAULT_TANK_NEAR_RATIO,
                   image_face=None) -> "PoseSweep":
        """This sweep with the tank meshed anew, graded towards ``focus_m`` (None: the poses of the copy's first
        call), its face ``image_face`` (if any) an image plane, sharing this sweep's sensor block and edge
        correction.

        For poses each on a tank mesh of its own, the sensor factorised once (a tank map's poses): the result is
        the sweep that the same arguments with ``focus_m``, ``tank_near_ratio`` and ``image_face`` would build.

        >>> from electrosense.meshes import Tank, preset
        >>> sweep = PoseSweep(preset("angels-2"), Tank((0.4, 0.3, 0.3)), edge_length_m=0.01)
        >>> pose = [[0.09, 0.0, 0.0, 0.0]]     # a tip 1 cm from the end wall
        >>> K0 = sweep.with_focus().conductance(pose).K_S
        >>> K1 = PoseSweep(preset("angels-2"), Tank((0.4, 0.3, 0.3)), edge_length_m=0.01).conductance(pose).K_S
        >>> bool(abs(K0 - K1).max() < 1e-9 * abs(K1).max())
        True
        """
        if self._given_tank_mesh is not None:
            raise ValueError("with_focus: this sweep was given its tank mesh; make a sweep with tank_mesh instead")
        new = copy.copy(self)
        new.focus_m = None if focus_m is None else np.asarray(focus_m, float).reshape(-1, 3)
        new.tank_near_ratio = tank_near_ratio
        new.image_faces, new.image_group = _image_faces(image_face, self.tank), None
        new.timings = dict(self.timings)
        if self.tank is not None or self.objects:
            new._env_ready, new._woodbury, new._A_e = False, None, None
        return new

    def _prepare_free(self):
        """Alone in unbounded water K does not depend on the pose: one solve, as :func:`electrosense.bem.solve.solve_scene`
        does it (the axisymmetric reduction for a sensor of revolution), and no sensor block at all."""

        wb = WaterBoundary.from_meshes(self.sensor_mesh, emitter=self.emitter, allow_touching=self._touching)
        self.sensor_boundary = wb
        if self.sensor.has_sectors:
            from electrosense.bem.symmetric import solve_symmetric
            from electrosense.meshes.sector_mesh import block_symmetry

            order, mirror = block_symmetry(self.sensor)
            solution = solve_symmetric(wb, self.sigma_S_per_m, self.contact_impedance_ohm_m2, self.emitter,
                                       order=order, mirror=mirror)
        elif is_axisymmetric_sensor(wb):
            solution = solve_axisymmetric(wb, self.sigma_S_per_m, self.contact_impedance_ohm_m2, self.emitter,
                                          targets_per_class=AXISYMMETRIC_TARGETS_PER_CLASS)
        else:
            solution = solve(wb, self.sigma_S_per_m, self.contact_impedance_ohm_m2, self.emitter)
        self._free_K = solution.K_S

    # ------------------------------------------------------------- invariant
    def _prepare_sensor(self):
        wb = WaterBoundary.from_meshes(self.sensor_mesh, emitter=self.emitter, allow_touching=self._touching)
        self.sensor_boundary = wb
        self.sensor_tris = TriangleSet(wb.triangles_m)  # sensor frame, normals out of the water
        self.scale_m = float(np.sqrt(np.mean(self.sensor_tris.areas)))
        cs, cd, grp = column_coefficients(wb, self.sigma_S_per_m, self.z_c, self.scale_m)
        self._cs_s, self._cd_s, self._grp_s = cs, cd, grp
        Ns = len(self.sensor_tris)
        check_memory(Ns, 1.1, what="the sensor block", fraction=0.8 * self.memory_share)
        cache = self._disk_cache(Ns)
        if cache is not None:
            key = cache.key(self.sensor_tris.triangles, cs, cd, grp, np.array([self.n]))
            found = cache.load(key, ("lu", "piv", "y0"))
            if found is not None:
                self._lu, self._piv, self._y0 = found
                self.timings["sensor_block_cached"] = True
                return self._electrode_maps(wb)
        A, B = mixed_system(self.sensor_tris.centroids, self.sensor_tris, np.arange(Ns), cs, cd, grp, self.n)
        # float32 factors: half the memory, cache and per-pose traffic of float64. y0 = A_ss^-1 r_s gets
        # float64 accuracy by iterative refinement; the per-pose correction W only carries the walls'
        # reflection, so its float32 rounding moves K by about 1e-8 (angels-4 in the 1 m tank).
        self._lu, self._piv, rcond = factorise(A.astype(np.float32), "sensor block")
        if rcond < 1e-6:   # too ill-conditioned for float32: float64 factors
            self._lu, self._piv, _ = factorise(A.copy(), "sensor block")
        self._y0, _ = solve_refined(A, -B, (self._lu, self._piv), "sensor block")
        del A
        if cache is not None:
            cache.save(key, {"lu": self._lu, "piv": self._piv, "y0": self._y0})
        self.timings["sensor_block_cached"] = False
        self._electrode_maps(wb)

    def _disk_cache(self, n_triangles: int):
        """The :class:`~electrosense.bem.block_cache.BlockCache` of a block of ``n_triangles`` unknowns, or None:
        ``block_cache`` True or a folder, or None and a block of :data:`~electrosense.bem.block_cache.CACHE_MIN_TRIANGLES`
        or more."""
        from electrosense.bem.block_cache import CACHE_MIN_TRIANGLES, BlockCache

        if self.block_cache or (self.block_cache is None and n_triangles >= CACHE_MIN_TRIANGLES):
            return BlockCache(None if self.block_cache in (None, True) else self.block_cache)
        return None

    def _electrode_maps(self, wb):
        on_e = wb.electrode > 0
        self._electrode_rows = np.flatnonzero(on_e)
        self._electrode_of_row = wb.electrode[on_e] - 1
        self._electrode_weight = (self.sigma_S_per_m / self.scale_m) * self.sensor_tris.areas[on_e]

    def _prepare_environment(self, poses: np.ndarray):
        from electrosense.meshes.object_mesh import mesh_object
        from electrosense.meshes.scene import Scene
        from electrosense.meshes.scene_mesh import mesh_tank_around, sensor_axis_points_m

        tank_mesh = self._given_tank_mesh
        if self.tank is not None and tank_mesh is None:
            if self.focus_m is None:
                self.focus_m = np.concatenate([sensor_axis_points_m(Scene(self.sensor, Pose.from_array(p), self.tank), 9)
                                               for p in poses])
            tank_mesh = mesh_tank_around(self.sensor, self.tank, self.focus_m, self.tank_edge_length_m,
                                         self.tank_grading, self.tank_near_ratio)
        object_meshes = tuple(mesh_object(o, None, region_name=f"object_{i}") for i, o in enumerate(self.objects, 1))
        if tank_mesh is None and not object_meshes:
            self.env_tris = None
            self._env_ready = True
            return
        # a boundary with the sensor at the origin gives the environment's column coefficients
        wb = WaterBoundary.from_meshes(self.sensor_mesh, tank_mesh, object_meshes,
                                       tuple(o.is_conducting for o in self.objects), emitter=self.emitter,
                                       allow_touching=self._touching)
        Ns = self.sensor_boundary.n_triangles
        self.env_boundary = wb
        meshed = np.ones(wb.n_triangles - Ns, bool)   # the environment's triangles in the system: all but an image's
        if self.image_faces:
            rest, self.image_group = split_image_faces(tank_mesh, self.image_faces)   # refuses what cannot be one
            meshed[:tank_mesh.n_triangles] = ~np.isin(tank_mesh.region,
                                                      [tank_mesh.region_index(f) for f in self.image_faces])
            tank_mesh = rest
        self.env_tris = TriangleSet(wb.triangles_m[Ns:][meshed])
        self.n_conductors = wb.n_conductors
        cs, cd, grp = column_coefficients(wb, self.sigma_S_per_m, self.z_c, self.scale_m)
        self._cs_e, self._cd_e, self._grp_e = cs[Ns:][meshed], cd[Ns:][meshed], grp[Ns:][meshed]
        conductor = wb.conductor[Ns:][meshed]
        Ne = len(self.env_tris)
        check_bytes(pose_bytes(Ns, Ne),
                    f"the tank ({Ne} triangles) and the sensor ({Ns}) blocks", 0.8 * self.memory_share)
        self.tank_mesh = tank_mesh
        # the environment's block depends on its triangles and column coefficients alone: its Woodbury factors
        # are kept on disk like the sensor's (a later process's sweep in the same tank mesh reads them back)
        cache = self._disk_cache(Ne) if self.cache_environment else None
        if cache is not None:
            plane = () if self.image_group is None else [a for p in self.image_group.planes
                                                         for a in (p.point_m, p.normal)]
            key = cache.key(np.frombuffer(b"environment-block", np.uint8), self.env_tris.triangles, self._cs_e,
                            self._cd_e, self._grp_e, conductor, np.array([self.n, self.n_conductors]), *plane)
            found = cache.load(key, ("lu", "piv", "c"))
            if found is not None:
                lu, piv, c = found
                self._A_e = None     # only the Woodbury factors are needed (cached only where they are safe)
                self._rank_one = self._rank_one_vectors(len(lu), float(c))
                self._woodbury = (lu, piv)
                self.timings.update(woodbury=True, environment_block_cached=True)
                self._env_ready = True
                return
        ng = self.n + self.n_conductors
        A, B = mixed_system(self.env_tris.centroids, self.env_tris, np.arange(Ne), self._cs_e, self._cd_e,
                            self._grp_e, ng, far=np.inf)  # exact solid angles: A_ee z = 0 exactly
        for points in self._images(self.env_tris.centroids):   # the images' terms, exact solid angles too
            A_image, B_image = mixed_system(points, self.env_tris, None, self._cs_e, self._cd_e, self._grp_e, ng,
                                            far=np.inf)
            A += A_image
            B += B_image
            del A_image
        nc = self.n_conductors
        if nc:
            M = np.zeros((Ne + nc, Ne + nc))
            M[:Ne, :Ne] = A
            M[:Ne, Ne:] = B[:, self.n:]
            mean_area = float(np.mean(self.env_tris.areas))
            for c in range(nc):
                M[Ne + c, :Ne] = np.where(conductor == c, self.env_tris.areas / mean_area, 0.0)
            A = M
        self._A_e = A   # (Ne + nc) square; singular alone in a closed tank, fine in the Schur complement
        c = self._prepare_woodbury()
        self.timings["environment_block_cached"] = False
        if cache is not None and self._woodbury is not None:
            cache.save(key, {"lu": self._woodbury[0], "piv": self._woodbury[1], "c": np.array(c)})
        self._env_ready = True

    @staticmethod
    def _rank_one_vectors(N: int, c: float) -> tuple:
        """The rank-one term ``c a b^T`` of the module doc as (sqrt(c) a, sqrt(c) b), a = b = 1 / sqrt(N)."""
        return np.full((N, 1), np.sqrt(c / N)), np.full((N, 1), np.sqrt(c / N))

    def _prepare_woodbury(self) -> float:
        """LU factors of ``A' = A_e + c a b^T`` (module doc), or None where ``A'`` is too ill-conditioned; returns c.

        The factors are float32 (half the time of float64; each pose's solve is refined on float64 residuals
        of ``A_e``) where ``A'`` is conditioned well enough (:data:`LOW_PRECISION_MIN_RCOND`) and ``A_e`` is
        kept, float64 where the factors go to the disk cache (``A_e`` itself is not kept there)."""
        N = len(self._A_e)
        c = float(np.abs(np.diag(self._A_e)).mean())   # the diagonal's scale: A' as well conditioned as A_e's range
        self._rank_one = self._rank_one_vectors(N, c)
        a, b = self._rank_one
        self._woodbury = None
        try:
            if not self.cache_environment:
                lu, piv, rcond = factorise((self._A_e + a @ b.T).astype(np.float32), "regularised tank block")
                if rcond >= max(LOW_PRECISION_MIN_RCOND, WOODBURY_MIN_RCOND):
                    self._woodbury = (lu, piv)
            if self._woodbury is None:
                lu, piv, rcond = factorise(self._A_e + a @ b.T, "regularised tank block")
                self._woodbury = (lu, piv) if rcond >= WOODBURY_MIN_RCOND else None
        except SingularSystemError:
            self._woodbury = None
        self.timings["woodbury"] = self._woodbury is not None
        return c

    # ------------------------------------------------------------------ poses
    def _coupling(self, pose):
        """A_se (Ns, Ne+nc), A_es (Ne+nc, Ns) and r_e (Ne+nc, n) at one pose."""
        R, t = rotation_z(pose[3]), pose[:3]
        s = self.sensor_tris
        tris_s = TriangleSet(s.triangles @ R.T + t)
        e = self.env_tris
        ng = self.n + self.n_conductors
        A_se, B_se = mixed_system(tris_s.centroids, e, None, self._cs_e, self._cd_e, self._grp_e, ng)
        A_es, B_es = mixed_system(e.centroids, tris_s, None, self._cs_s, self._cd_s, self._grp_s, self.n)
        for points in self._images(tris_s.centroids):
            A_image, B_image = mixed_system(points, e, None, self._cs_e, self._cd_e, self._grp_e, ng)
            A_se += A_image
            B_se += B_image
        for points in self._images(e.centroids):
            A_image, B_image = mixed_system(points, tris_s, None, self._cs_s, self._cd_s, self._grp_s, self.n)
            A_es += A_image
            B_es += B_image
        nc = self.n_conductors
        if nc:
            A_se = np.hstack([A_se, B_se[:, self.n:]])
            A_es = np.vstack([A_es, np.zeros((nc, A_es.shape[1]))])
            B_es = np.vstack([B_es, np.zeros((nc, B_es.shape[1]))])
        return A_se, A_es, -B_es

    #: the sensor-tank coupling from its rows and columns where it pays (:data:`COUPLING_CROSS_MIN_TRIANGLES`;
    #: False: assembled, the reference the tests compare with)
    coupling_by_cross_approximation = True

    def _coupling_low_rank(self, pose):
        """``(P_se, Vt, (U_es, V_es), r_e)`` at one pose, or None (assemble :meth:`_coupling` instead): ``A_se ~
        P_se Vt`` (``Vt`` orthonormal rows, truncated at ``tol`` of its largest singular value, as the assembled
        block's are by :func:`~electrosense.bem.low_rank.right_singular_vectors`), ``A_es ~ U_es V_es`` and the
        tank's right-hand side ``r_e`` (Ne, n) from the electrodes' double layer, ``~ U V G`` with ``G`` summing
        each electrode's columns: each block from some of its rows and columns
        (:func:`~electrosense.bem.cross_approximation.cross_approximation`, to :data:`COUPLING_CROSS_TOL_FACTOR`
        x ``tol`` in the Frobenius norm, the tank's rows to :data:`COUPLING_RHS_CROSS_TOL_FACTOR` x ``tol``),
        images included. Only without objects, on a sensor mesh of :data:`COUPLING_CROSS_MIN_TRIANGLES` or more at
        a ``tol`` of ``IMAGE_CROSS_MIN_TOL`` or more; None where a block does not converge in a quarter of its
        smaller side, and once more have not converged than have on this sensor (its sweep and every
        :meth:`with_focus` copy), every pose is assembled: a failure costs several assemblies."""
        tally = self._coupling_cross_tally
        if (not self.coupling_by_cross_approximation or self.objects or self.n_conductors
                or len(self.sensor_tris) < COUPLING_CROSS_MIN_TRIANGLES or self.tol < IMAGE_CROSS_MIN_TOL
                or tally["not"] > tally["converged"]):
            return None
        from scipy.spatial import cKDTree

        R, t = rotation_z(pose[3]), pose[:3]
        s = TriangleSet(self.sensor_tris.triangles @ R.T + t)
        e = self.env_tris
        rows_s = [s.centroids, *self._images(s.centroids)]
        rows_e = [e.centroids, *self._images(e.centroids)]
        # the first pivots where the blocks are largest: the sensor's and the tank's points nearest each other
        d_s, nearest_e = cKDTree(e.centroids).query(s.centroids)
        first_s = int(np.argmin(d_s))
        first_e = int(nearest_e[first_s])
        Ns, Ne = len(s), len(e)
        every_s, every_e = np.arange(Ns), np.arange(Ne)
        on_e = np.flatnonzero((self._grp_s >= 0) & (self._grp_s < self.n))
        blocks = (
            (rows_s, e, every_e, self._cs_e, self._cd_e, first_s),                        # A_se
            (rows_e, s, every_s, self._cs_s, self._cd_s, first_e),                        # A_es
            (rows_e, s, on_e, np.zeros(Ns), np.ones(Ns), first_e),                        # D over the electrodes
        )
        low = []
        for i, (points, tris, cols, c_single, c_double, first) in enumerate(blocks):
            factor = COUPLING_CROSS_TOL_FACTOR if i == 0 else COUPLING_RHS_CROSS_TOL_FACTOR
            M = _cross_approximated_block(points, tris, cols, c_single, c_double, factor * self.tol, first,
                                            max_rank=min(len(points[0]), len(cols)) // 4)
            if M is None:
                tally["not"] += 1
                return None
            low.append(M)
        tally["converged"] += 1
        P_se, Vt, _ = recompressed(*low[0], self.tol)
        G = np.zeros((len(on_e), self.n))
        G[np.arange(len(on_e)), self._grp_s[on_e]] = 1.0
        U_d, V_d = low[2]
        return P_se, Vt, low[1], -(U_d @ (V_d @ G))

    def _check_pose(self, pose):
        from electrosense.meshes.scene import Scene
        from electrosense.meshes.scene_mesh import check_scene

        check_scene(Scene(self.sensor, Pose.from_array(pose), self.tank, self.objects))

    def _solve_pose(self, pose):
        """The sensor's unknowns (Ns, n) at one pose, the rank kept of the coupling, and the environment's
        unknowns (Ne + nc, n: the potential on the tank's faces, then the objects')."""
        low = self._coupling_low_rank(pose)
        if low is not None:   # A_se ~ P_se Vt, A_es ~ U_es V_es from their rows and columns
            P_se, Vt, (U_es, V_es), r_e = low

            def A_es_times(X):
                return U_es @ (V_es @ X)
        else:
            A_se, A_es, r_e = self._coupling(pose)
            # dominant right singular vectors by blocked randomised range finding (bem.low_rank: a few products
            # with about rank vectors, where the Gram matrix and its eigendecomposition cost Ns Ne^2 + Ne^3); it
            # depends on A_se alone, so a pose's K does not depend on which worker computed it or after which pose;
            # A_se V_k = U_k s_k, so W V_k^T = A_ss^-1 A_se V_k V_k^T
            Vt, _ = right_singular_vectors(A_se, self.tol)
            P_se = A_se @ Vt.T

            def A_es_times(X):
                return A_es @ X
        k = len(Vt)
        y0, sensor_solve = self._sensor_block_at(pose)
        W = sensor_solve(P_se)
        f = r_e - A_es_times(y0)
        if self._woodbury is not None:
            a, b = self._rank_one
            AW = A_es_times(W)
            U = np.hstack([a, AW])
            C = np.vstack([b.T, Vt])
            low = self._woodbury[0].dtype

            def inverse_of_A_prime(r):
                return scipy.linalg.lu_solve(self._woodbury, r.astype(low), check_finite=False).astype(float)

            Z = inverse_of_A_prime(U)
            capacitance = np.eye(k + 1) - C @ Z
            lu, piv, _ = factorise(capacitance, f"system at pose {pose.tolist()}")

            def woodbury(r):   # (A' - U C)^-1 r = (A_e - A_es W V_k^T)^-1 r, to the factors' precision
                g = inverse_of_A_prime(r)
                return g + Z @ scipy.linalg.lu_solve((lu, piv), C @ g, check_finite=False)

            y_e = woodbury(f)
            if low != np.float64:   # refined on float64 residuals of the Schur complement
                y_e, _ = refine(lambda y: self._A_e @ y - AW @ (Vt @ y), f, y_e, woodbury,
                                f"system at pose {pose.tolist()}", REFINEMENT_TOL, MAX_REFINEMENTS)
        else:
            schur = self._A_e - A_es_times(W) @ Vt
            lu, piv, _ = factorise(schur, f"system at pose {pose.tolist()}")
            y_e = scipy.linalg.lu_solve((lu, piv), f, check_finite=False)
        return y0 - W @ (Vt @ y_e), k, y_e

    def _images(self, points_m) -> list:
        """The images of ``points_m`` in the image planes (none without them)."""
        return [] if self.image_group is None else self.image_group.images(points_m)

    def _sensor_block_at(self, pose):
        """(``y0``, ``solve``): the sensor block's solution for the electrodes' potentials and its solver at
        ``pose``. Without image planes the block is the pose's invariant ``A_ss`` (stored factors). With them it
        is ``A_ss + M``, ``M`` the sum of the sensor's own images (its collocation points reflected: smooth
        kernels at least twice the gap away), of low rank: ``M ~ P Q^T`` with ``Q^T`` its right singular vectors
        to :data:`IMAGE_TOL_FACTOR` x ``tol`` (:meth:`_sensor_image_low_rank`), solved by the Woodbury formula on
        the stored factors, ``(A + P Q^T)^-1 = A^-1 - A^-1 P (I + Q^T A^-1 P)^-1 Q^T A^-1``."""
        def stored(r):
            return scipy.linalg.lu_solve((self._lu, self._piv), r.astype(self._lu.dtype), check_finite=False
                                         ).astype(float)

        if self.image_group is None:
            return self._y0, stored
        R, t = rotation_z(pose[3]), pose[:3]
        s = TriangleSet(self.sensor_tris.triangles @ R.T + t)
        P, Qt, B_image = self._sensor_image_low_rank(s)
        AinvP = stored(P)
        capacitance = scipy.linalg.lu_factor(np.eye(len(Qt)) + Qt @ AinvP, check_finite=False)

        def solve(r):
            g = stored(r)
            return g - AinvP @ scipy.linalg.lu_solve(capacitance, Qt @ g, check_finite=False)

        z = self._y0 - stored(B_image)          # A^-1 (r_s + r_image), r = -B
        y0 = z - AinvP @ scipy.linalg.lu_solve(capacitance, Qt @ z, check_finite=False)
        return y0, solve

    #: the sensor's own image from its rows and columns (:mod:`~electrosense.bem.cross_approximation`) rather than
    #: assembled whole (False: assembled, the reference the tests compare with)
    image_by_cross_approximation = True

    def _electrodes_double_layer_at(self, s, images) -> np.ndarray:
        """Each electrode's double layer summed over the ``images`` of the sensor's collocation points (N, n):
        :func:`~electrosense.bem.operators.mixed_system`'s ``B`` over the electrodes' triangles alone."""
        on_e = np.flatnonzero((self._grp_s >= 0) & (self._grp_s < self.n))
        electrodes = TriangleSet(s.triangles[on_e])
        none = np.zeros(len(on_e))
        return sum(mixed_system_reduced(points, electrodes, None, none, none, self._grp_s[on_e], self.n,
                                        np.zeros(len(on_e), np.int64), 1)[1] for points in images)

    def _sensor_image_low_rank(self, s):
        """``(P, Qt, B)`` of the sensor's own images at its placed triangles ``s``: ``M ~ P Qt`` (``Qt``
        orthonormal rows, to :data:`IMAGE_TOL_FACTOR` x ``tol`` of ``M``'s largest singular value) and ``B`` (N,
        n), each electrode's double layer at the image points (the right-hand side's part).

        ``M`` is of rank 36-56 at 1e-6 (a random 4-electrode sensor of 8 242 triangles 5-12 mm from a wall):
        its cross approximation evaluates some hundred of its rows and columns where the assembly evaluates
        all ``N^2`` entries of each image and its SVD costs a third as much again (a reference pose of the tank
        map 1.6-1.8x faster; :data:`IMAGE_CROSS_MIN_TRIANGLES`); ``B`` is summed over the electrodes' triangles
        alone. A block that does not converge in ``N / 16`` terms is assembled, and once three more have not
        converged than have on this sensor (its sweep and every :meth:`with_focus` copy), every block is."""
        images = self._images(s.centroids)
        N, tol = len(s), IMAGE_TOL_FACTOR * self.tol
        cross_tol, tally = IMAGE_CROSS_TOL_FACTOR * tol, self._image_cross_tally
        if (self.image_by_cross_approximation and N >= IMAGE_CROSS_MIN_TRIANGLES and cross_tol >= IMAGE_CROSS_MIN_TOL
                and tally["not"] <= tally["converged"] + 2):
            first = int(np.argmin(np.min([np.linalg.norm(p - s.centroids, axis=1) for p in images], axis=0)))
            M = _cross_approximated_block(images, s, np.arange(N), self._cs_s, self._cd_s, cross_tol, first)
            tally["not" if M is None else "converged"] += 1
            if M is not None:
                P, Qt, _ = recompressed(*M, tol)
                return P, Qt, self._electrodes_double_layer_at(s, images)
        M = B_image = None
        for points in images:
            M_k, B_k = mixed_system(points, s, None, self._cs_s, self._cd_s, self._grp_s, self.n)
            if M is None:
                M, B_image = M_k, B_k
            else:                  # in place: the block is the sensor's size (0.56 GB for 8 400 triangles)
                M += M_k
                B_image += B_k
            del M_k
        Qt, _ = right_singular_vectors(M, tol)
        return M @ Qt.T, Qt, B_image

    def conductance(self, poses, progress: bool = False, check: bool = True,
                    wall_derivatives: bool = False) -> ConductanceMatrix:
        """Conductance matrices for poses (P, 4) (x, y, z, yaw): K_S of shape (P, n, n).

        ``wall_derivatives``: also ``info["dK_dwall_S_per_m"]`` (P, regions, n, n), the change of K per metre
        that each of the tank mesh's regions (``info["wall_regions"]``, e.g. ``wall_x+`` or ``free_surface``)
        moves outward, and, with no objects in the tank, ``info["dK_dpose"]`` (P, 3, n, n), the change of K
        with the sensor's x, y (per metre) and yaw (per radian), from each pose's own solution
        (:mod:`electrosense.bem.shape_derivative`).
        """
        poses = poses_array(poses)
        if wall_derivatives and self.image_faces:
            raise ValueError(f"wall_derivatives: {', '.join(self.image_faces)}: an image plane, not a mesh, has no "
                             "panels to move; make the sweep without image_face")
        t0 = time.perf_counter()
        if check:
            for p in poses:
                self._check_pose(p)
        if not self._env_ready:
            self._prepare_environment(poses)
            self.timings["tank_block_s"] = time.perf_counter() - t0
        K = np.empty((len(poses), self.n, self.n))
        ranks = np.zeros(len(poses), int)
        iterator = range(len(poses))
        if progress:
            from tqdm import tqdm

            iterator = tqdm(iterator, desc="BEM poses", unit="pose")
        unbounded = self.tank is None
        walls = self._wall_operator() if wall_derivatives else None
        dK_walls = None if walls is None else np.zeros((len(poses), walls[1].shape[0], self.n, self.n))
        dK_pose = None if walls is None or self.objects else np.zeros((len(poses), 3, self.n, self.n))
        for p in iterator:
            if self.env_tris is None:
                K[p] = self._free_K + self._K_correction
                continue
            y_s, ranks[p], y_e = self._solve_pose(poses[p])
            if walls is not None:
                op, regions, normals = walls
                velocities = regions if dK_pose is None else sp.vstack([regions, _pose_velocities(op, normals,
                                                                                                   poses[p])])
                part = self._sensor_part_on_walls(poses[p], y_s, op)
                dK = shape_derivatives(op, y_e[:op.areas_m2.size], velocities, self.sigma_S_per_m, part)
                dK_walls[p] = dK[:regions.shape[0]]
                if dK_pose is not None:
                    dK_pose[p] = dK[regions.shape[0]:]
            C = np.zeros((self.n, self.n))
            np.add.at(C, self._electrode_of_row, self._electrode_weight[:, None] * y_s[self._electrode_rows])
            K[p] = self._corrected(isolate(C) if unbounded else C)
        seconds = time.perf_counter() - t0
        info = {"model": "bem", "triangles": int(self.sensor_mesh.n_triangles + (0 if self.env_tris is None else len(self.env_tris))),
                "sensor_triangles": int(self.sensor_mesh.n_triangles), "seconds": seconds,
                "coupling_rank": ranks.tolist(), **self.timings,
                "edge_correction_max_relative": float(np.abs(self._K_correction).max() / np.abs(K).max())}
        if dK_walls is not None:
            info.update(dK_dwall_S_per_m=dK_walls, wall_regions=tuple(self.tank_mesh.region_names))
        if dK_pose is not None:
            info.update(dK_dpose=dK_pose)
        g = ConductanceMatrix(K, self.emitter, self.sigma_S_per_m, info)
        info.update(asymmetry=g.asymmetry, row_sum_residue=g.row_sum_residue)
        return g

    def _sensor_part_on_walls(self, pose, y_s, op):
        """(faces, values, gradients): the sensor's layers' part of the unit solutions' potential on the tank's
        faces within :data:`WALL_SPLIT_RADIUS_FACTOR` sensor lengths of its axis, and its gradient along them
        (:func:`electrosense.bem.shape_derivative.layer_part`)."""
        R, t = rotation_z(pose[3]), pose[:3]
        half = 0.5 * self.sensor.length_m
        axis = t + R[:, 0] * np.clip((op.centroids_m - t) @ R[:, 0], -half, half)[:, None]
        faces = np.flatnonzero(np.linalg.norm(op.centroids_m - axis, axis=1)
                               < WALL_SPLIT_RADIUS_FACTOR * self.sensor.length_m)
        if not len(faces):
            return None
        wb = self.sensor_boundary
        on_e = wb.electrode > 0
        q = np.where(on_e[:, None], y_s / self.scale_m, 0.0)
        u = np.where(on_e[:, None], 0.0, y_s)
        k = wb.electrode[on_e] - 1
        u[on_e] = (np.arange(self.n)[None, :] == k[:, None]) - (self.z_c[k] * self.sigma_S_per_m)[:, None] * q[on_e]
        tris = TriangleSet(self.sensor_tris.triangles @ R.T + t)
        values, grads = layer_part(op.centroids_m[faces], op.tangents[faces], tris, u, q)
        return faces, values, grads

    def _wall_operator(self):
        """(gradient operator, (regions, F) sparse indicator of each region's faces, (F, 3) outward normals) of
        the tank mesh, built once; None in unbounded water."""
        if self.tank is None or not self._env_ready:
            return None
        if getattr(self, "_walls", None) is None:
            tm = self.tank_mesh
            T = tm.triangles_m
            cross = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
            region = np.asarray(tm.region, int)
            regions = sp.csr_matrix((np.ones(len(region)), (region, np.arange(len(region)))),
                                    shape=(len(tm.region_names), len(region)))
            self._walls = (surface_gradient_operator(T), regions, cross / np.linalg.norm(cross, axis=1, keepdims=True))
        return self._walls


def _cross_approximated_block(point_sets, s, cols, c_single, c_double, tol: float, first_row: int,
                              max_rank: int | None = None):
    """The cross approximation (:func:`~electrosense.bem.cross_approximation.cross_approximation`) of the sum
    over ``point_sets`` (each (N, 3): the rows' points, or their images) of
    :func:`~electrosense.bem.operators.mixed_entries` on the triangles ``s``'s columns ``cols``: ``(U, V)`` or
    None past ``max_rank`` terms (default N / 16)."""
    n_rows, every = len(point_sets[0]), np.arange(len(point_sets[0]))

    def row(i):
        out = np.zeros((1, len(cols)))
        for points in point_sets:
            mixed_entries(points, s, [i], cols, c_single, c_double, out=out)
        return out[0]

    def column(j):
        out = np.zeros((n_rows, 1))
        for points in point_sets:
            mixed_entries(points, s, every, cols[j:j + 1], c_single, c_double, out=out)
        return out[:, 0]

    return cross_approximation(row, column, (n_rows, len(cols)), tol,
                               max_rank=n_rows // 16 if max_rank is None else max_rank, first_row=first_row)
