"""Many poses of one sensor in one tank, reusing everything that does not move.

Split the unknowns into the sensor's ``s`` (rigid: its own block ``A_ss`` is
the same in every pose, computed in the sensor frame) and the environment's
``e`` (tank walls, floor, free surface and objects, fixed in the tank frame:
``A_ee``). Only the coupling blocks ``A_se`` and ``A_es`` change with the pose::

    [A_ss  A_se] [y_s]   [r_s]
    [A_es  A_ee] [y_e] = [r_e]

Both diagonal blocks are LU-factorised once. Per pose, the coupling blocks
are assembled and the sensor's unknowns solve the Schur system
preconditioned by ``A_ss``::

    (I - A_ss^-1 A_se A_ee^-1 A_es) y_s = A_ss^-1 (r_s - A_se A_ee^-1 r_e),

by block GMRES on all electrodes' right-hand sides at once (a Krylov space
of blocks, the residual minimised by least squares). The operator is the
identity plus the walls' reflection of the sensor's field, so a handful of
iterations suffice; each one costs two coupling products and two triangular
solves, O(N^2), against the O(N^3) of a fresh factorisation.

The tank mesh is graded towards the whole trajectory (the sensor's axis at
every pose of the first batch, or ``focus_m``), so that one tank mesh serves
every pose. ``PoseSweep`` holds only numpy arrays: it pickles, and its
pose-invariant state can be scattered to workers.

Example
-------
>>> import numpy as np
>>> from meshes import Tank, preset
>>> from bem.sweep import PoseSweep
>>> sweep = PoseSweep(preset("angels-2"), Tank((1.0, 1.0, 1.0)), sigma_S_per_m=0.0354)   # doctest: +SKIP
>>> g = sweep.conductance(np.array([[0.0, 0, 0, 0], [0.2, 0, 0, 0]]))                   # doctest: +SKIP
>>> g.K_S.shape                                                                         # doctest: +SKIP
(2, 2, 2)
"""
from __future__ import annotations

import time

import numpy as np
import scipy.linalg

from meshes.pose import Pose, poses_array, rotation_z

from .boundary_conditions import BoundaryError, WaterBoundary
from .conductance import ConductanceMatrix, isolate
from .memory import check_memory
from .operators import TriangleSet, mixed_system
from .solve import factorise
from .system import column_coefficients, contact_impedances

__all__ = ["PoseSweep", "block_gmres"]


def block_gmres(apply, rhs: np.ndarray, tol: float = 1e-10, max_iterations: int = 200):
    """Solve ``apply(Y) = rhs`` for a block of right-hand sides (N, k) by block GMRES.

    The Krylov space of blocks ``rhs, apply(rhs), ...`` is orthonormalised;
    the coefficients minimise the Frobenius norm of the residual (least
    squares on the stored images). Returns ``(Y, iterations, relative residual)``.
    """
    norm_rhs = np.linalg.norm(rhs)
    if norm_rhs == 0:
        return np.zeros_like(rhs), 0, 0.0
    basis, _ = np.linalg.qr(rhs)
    V = basis
    Z = apply(V)
    residual = np.inf
    for it in range(1, max_iterations + 1):
        coef, *_ = np.linalg.lstsq(Z, rhs, rcond=None)
        residual = np.linalg.norm(Z @ coef - rhs) / norm_rhs
        if residual < tol or it == max_iterations:
            return V @ coef, it, residual
        new = Z[:, -basis.shape[1]:]
        new = new - V @ (V.T @ new)
        new = new - V @ (V.T @ new)
        q, r = np.linalg.qr(new)
        keep = np.abs(np.diag(r)) > 1e-14 * np.linalg.norm(new)
        if not keep.any():
            return V @ coef, it, residual
        q = q[:, keep]
        basis = q
        V = np.hstack([V, q])
        Z = np.hstack([Z, apply(q)])
    return V @ coef, max_iterations, residual


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
    focus_m : (P, 3) array, optional
        Tank-frame points the tank mesh is graded towards; default: the
        sensor's axis at every pose of the first call.
    tol : float
        Relative residual of the block GMRES per pose.

    Example
    -------
    See the module docstring.
    """

    def __init__(self, sensor, tank=None, objects=(), sigma_S_per_m: float = 1.0, contact_impedance_ohm_m2=None,
                 edge_length_m=None, tank_edge_length_m=None, focus_m=None, tol: float = 1e-9, **sensor_mesh_options):
        from meshes.sensor_mesh import mesh_sensor

        if not (np.isfinite(sigma_S_per_m) and sigma_S_per_m > 0):
            raise ValueError(f"sigma_S_per_m must be a positive conductivity, got {sigma_S_per_m}")
        from .solve import check_object_materials

        check_object_materials(objects)
        self.sensor = sensor
        self.tank = tank
        self.objects = tuple(objects)
        self.sigma_S_per_m = float(sigma_S_per_m)
        self.contact_impedance_ohm_m2 = contact_impedance_ohm_m2
        self.tank_edge_length_m = tank_edge_length_m
        self.focus_m = None if focus_m is None else np.asarray(focus_m, float).reshape(-1, 3)
        self.tol = float(tol)
        self.sensor_mesh = mesh_sensor(sensor, edge_length_m=edge_length_m, **sensor_mesh_options)
        self.n = sensor.n_electrodes
        self.emitter = sensor.emitter
        self.z_c = contact_impedances(contact_impedance_ohm_m2, self.n)
        self._env_ready = False
        self.timings = {}
        t0 = time.perf_counter()
        self._prepare_sensor()
        self.timings["sensor_block_s"] = time.perf_counter() - t0

    # ------------------------------------------------------------- invariant
    def _prepare_sensor(self):
        wb = WaterBoundary.from_meshes(self.sensor_mesh, emitter=self.emitter)
        self.sensor_boundary = wb
        self.sensor_tris = TriangleSet(wb.triangles_m)  # sensor frame, normals out of the water
        self.scale_m = float(np.sqrt(np.mean(self.sensor_tris.areas)))
        cs, cd, grp = column_coefficients(wb, self.sigma_S_per_m, self.z_c, self.scale_m)
        self._cs_s, self._cd_s, self._grp_s = cs, cd, grp
        Ns = len(self.sensor_tris)
        check_memory(Ns, 1.2, what="the sensor block")
        A, B = mixed_system(self.sensor_tris.centroids, self.sensor_tris, np.arange(Ns), cs, cd, grp, self.n)
        self._r_s = -B  # (Ns, n)
        # the explicit inverse: every pose applies it to thin blocks, and a matrix product runs at
        # full BLAS speed where triangular solves with a few right-hand sides do not
        lu, piv, _ = factorise(A, "sensor block")
        self._inv_s = scipy.linalg.lu_solve((lu, piv), np.eye(Ns), check_finite=False)
        on_e = wb.electrode > 0
        self._electrode_rows = np.flatnonzero(on_e)
        self._electrode_of_row = wb.electrode[on_e] - 1
        self._electrode_weight = (self.sigma_S_per_m / self.scale_m) * self.sensor_tris.areas[on_e]

    def _prepare_environment(self, poses: np.ndarray):
        from meshes.object_mesh import mesh_object
        from meshes.scene_mesh import sensor_axis_points_m
        from meshes.scene import Scene
        from meshes.tank_mesh import mesh_tank

        tank_mesh = None
        if self.tank is not None:
            if self.focus_m is None:
                self.focus_m = np.concatenate([sensor_axis_points_m(Scene(self.sensor, Pose.from_array(p), self.tank), 9)
                                               for p in poses])
            h = self.sensor.length_m / 10 if self.tank_edge_length_m is None else self.tank_edge_length_m
            tank_mesh = mesh_tank(self.tank, h, self.focus_m)
        object_meshes = tuple(mesh_object(o, None, region_name=f"object_{i}") for i, o in enumerate(self.objects, 1))
        if tank_mesh is None and not object_meshes:
            self.env_tris = None
            self._env_ready = True
            return
        # a boundary with the sensor at the origin gives the environment's column coefficients
        wb = WaterBoundary.from_meshes(self.sensor_mesh, tank_mesh, object_meshes,
                                       tuple(o.is_conducting for o in self.objects), emitter=self.emitter)
        Ns = self.sensor_boundary.n_triangles
        self.env_boundary = wb
        self.env_tris = TriangleSet(wb.triangles_m[Ns:])
        self.n_conductors = wb.n_conductors
        cs, cd, grp = column_coefficients(wb, self.sigma_S_per_m, self.z_c, self.scale_m)
        self._cs_e, self._cd_e, self._grp_e = cs[Ns:], cd[Ns:], grp[Ns:]
        Ne = len(self.env_tris)
        check_memory(Ne + Ns, 1.3, what="the tank and sensor blocks")
        ng = self.n + self.n_conductors
        A, B = mixed_system(self.env_tris.centroids, self.env_tris, np.arange(Ne), self._cs_e, self._cd_e,
                            self._grp_e, ng, far=np.inf)  # exact solid angles: A_ee z = 0 exactly
        nc = self.n_conductors
        if nc:
            M = np.zeros((Ne + nc, Ne + nc))
            M[:Ne, :Ne] = A
            M[:Ne, Ne:] = B[:, self.n:]
            conductor = wb.conductor[Ns:]
            mean_area = float(np.mean(self.env_tris.areas))
            for c in range(nc):
                M[Ne + c, :Ne] = np.where(conductor == c, self.env_tris.areas / mean_area, 0.0)
            A = M
        # In a closed tank the environment block alone is singular: a constant potential on the
        # walls (and conductors) carries no current, A_ee z = 0. Factorise A_ee + w v^T instead and
        # carry the tank's constant as one more unknown c with the solvability condition psi^T f = 0.
        z = np.zeros(len(A))
        z[:Ne] = np.where((self._cs_e == 0.0) & (self._grp_e < 0), 1.0, 0.0)
        z[Ne:] = 1.0
        self._bordered = self.tank is not None and np.linalg.norm(A @ z) < 1e-8 * np.linalg.norm(z) * np.abs(A).max()
        if self._bordered:
            v = z / np.linalg.norm(z)
            A += 0.5 * np.outer(v, v)
        lu, piv, _ = factorise(A, "tank block")
        self._inv_e = scipy.linalg.lu_solve((lu, piv), np.eye(len(A)), check_finite=False)
        if self._bordered:
            psi = self._inv_e.T @ v
            self._z_e = z
            self._psi_e = psi / np.abs(psi).max()
        self.tank_mesh = tank_mesh
        self._env_ready = True

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
        nc = self.n_conductors
        if nc:
            A_se = np.hstack([A_se, B_se[:, self.n:]])
            A_es = np.vstack([A_es, np.zeros((nc, A_es.shape[1]))])
            B_es = np.vstack([B_es, np.zeros((nc, B_es.shape[1]))])
        return A_se, A_es, -B_es

    def _check_pose(self, pose):
        from meshes.scene import Scene
        from meshes.scene_mesh import check_scene

        check_scene(Scene(self.sensor, Pose.from_array(pose), self.tank, self.objects))

    def _solve_pose(self, pose):
        if self.env_tris is None:
            return self._inv_s @ self._r_s, 0, 0.0
        A_se, A_es, r_e = self._coupling(pose)
        inv_s, inv_e = self._inv_s, self._inv_e
        Ns = A_se.shape[0]

        def solve_s(f):
            return inv_s @ f

        def solve_e(f):
            return inv_e @ f

        rhs = solve_s(self._r_s - A_se @ solve_e(r_e))
        if self._bordered:
            # unknowns [y_s; c]: y_e = A~^-1 (r_e - A_es y_s) + c z, with psi^T (r_e - A_es y_s) = 0
            coupling_z = solve_s(A_se @ self._z_e)
            psi_A_es = self._psi_e @ A_es

            def apply(Y):
                y, c = Y[:Ns], Y[Ns:]
                top = y - solve_s(A_se @ solve_e(A_es @ y)) + coupling_z[:, None] * c
                return np.vstack([top, psi_A_es @ y])

            rhs = np.vstack([rhs, self._psi_e @ r_e])
        else:
            def apply(Y):
                return Y - solve_s(A_se @ solve_e(A_es @ Y))

        y_s, iterations, residual = block_gmres(apply, rhs, self.tol)
        if residual > 1e3 * self.tol:
            raise BoundaryError(f"pose {pose.tolist()}: the sensor-tank iteration did not converge "
                                f"(residual {residual:.1e} after {iterations} iterations)")
        return y_s[:Ns], iterations, residual

    def conductance(self, poses, progress: bool = False, check: bool = True) -> ConductanceMatrix:
        """Conductance matrices for poses (P, 4) (x, y, z, yaw): K_S of shape (P, n, n)."""
        poses = poses_array(poses)
        t0 = time.perf_counter()
        if check:
            for p in poses:
                self._check_pose(p)
        if not self._env_ready:
            self._prepare_environment(poses)
            self.timings["tank_block_s"] = time.perf_counter() - t0
        K = np.empty((len(poses), self.n, self.n))
        iterations = np.zeros(len(poses), int)
        iterator = range(len(poses))
        if progress:
            from tqdm import tqdm

            iterator = tqdm(iterator, desc="BEM poses", unit="pose")
        unbounded = self.tank is None
        for p in iterator:
            y_s, iterations[p], _ = self._solve_pose(poses[p])
            C = np.zeros((self.n, self.n))
            np.add.at(C, self._electrode_of_row, self._electrode_weight[:, None] * y_s[self._electrode_rows])
            K[p] = isolate(C) if unbounded else C
        seconds = time.perf_counter() - t0
        info = {"model": "bem", "triangles": int(self.sensor_mesh.n_triangles + (0 if self.env_tris is None else len(self.env_tris))),
                "sensor_triangles": int(self.sensor_mesh.n_triangles), "seconds": seconds,
                "iterations": iterations.tolist(), **self.timings}
        g = ConductanceMatrix(K, self.emitter, self.sigma_S_per_m, info)
        info.update(asymmetry=g.asymmetry, row_sum_residue=g.row_sum_residue)
        return g
