"""Solving the collocation system: surface solutions and the conductance matrix.

:func:`solve` factorises the dense system once (LU) and solves it for one
right-hand side per electrode (electrode ``k`` at 1 V, the others at 0 V).
Everything is linear in the electrode potentials, so the resulting
:class:`BemSolution` gives the surface solution, the fields and the currents
for any potentials.

Currents. The current leaving electrode ``m`` into the water is
``sigma * sum_j a_j q_j`` over its faces. In a closed tank the currents of
the unit solutions form the isolated ``K`` directly. In unbounded water they
form the grounded ``C`` (far field at 0 V), and the isolated sensor's ``K``
is ``bem.conductance.isolate(C)``: the sensor floats to the common potential
at which its currents sum to zero.

Example
-------
>>> from meshes import Scene, preset
>>> from bem.solve import conductance_matrix
>>> g = conductance_matrix(Scene(preset("angels-2")), sigma_S_per_m=1.0)
>>> round(float(g.S_S[0, 0]), 3)          # doctest: +SKIP
0.035
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from .boundary_conditions import BoundaryError, WaterBoundary
from .conductance import ConductanceMatrix, isolate
from .system import BemSystem, assemble_system

__all__ = ["BemSolution", "solve", "solve_scene", "conductance_matrix", "factorise", "solve_refined",
           "SingularSystemError"]


#: collocation points per ring class of the axisymmetric reduction in :func:`solve_scene`
AXISYMMETRIC_TARGETS_PER_CLASS = 16


class SingularSystemError(BoundaryError):
    """The BEM system is singular (or numerically so)."""


def factorise(matrix: np.ndarray, what: str = "BEM system"):
    """LU factors of ``matrix`` (overwritten), refusing singular systems with a clear message."""
    norm1 = np.linalg.norm(matrix, 1)
    with warnings.catch_warnings():
        warnings.simplefilter("error", scipy.linalg.LinAlgWarning)
        try:
            lu, piv = scipy.linalg.lu_factor(matrix, overwrite_a=True, check_finite=False)
        except (scipy.linalg.LinAlgWarning, np.linalg.LinAlgError) as exc:
            raise SingularSystemError(f"the {what} is singular ({exc}); is every part closed and every "
                                      "electrode separated from the others?") from None
    gecon, = scipy.linalg.get_lapack_funcs(("gecon",), (lu,))
    rcond, info = gecon(lu, norm1, norm="1")
    if not np.isfinite(rcond) or rcond < 1e-14:
        raise SingularSystemError(f"the {what} is numerically singular (reciprocal condition number {rcond:.1e}); "
                                  "check for overlapping or touching parts and degenerate triangles")
    return lu, piv, float(rcond)


def solve_dense(matrix: np.ndarray, rhs: np.ndarray, what: str = "BEM system", precision: str = "mixed",
                refinement_tol: float = 1e-12, max_refinements: int = 6):
    """Solve ``matrix @ X = rhs``; returns ``(X, rcond, refinements)``.

    ``precision="mixed"``: LU in float32 (half the memory traffic and twice
    the speed of float64), then iterative refinement with float64 residuals
    until the relative residual is below ``refinement_tol`` (the answer has
    float64 accuracy for any reasonably conditioned BEM system).
    ``"double"``: LU in float64, factorising ``matrix`` in place.
    """
    if precision == "double":
        lu, piv, rcond = factorise(matrix, what)
        return scipy.linalg.lu_solve((lu, piv), rhs, check_finite=False), rcond, 0
    if precision != "mixed":
        raise ValueError(f"precision must be 'mixed' or 'double', got {precision!r}")
    lu, piv, rcond = factorise(matrix.astype(np.float32), what)
    if rcond < 1e-6:  # too ill-conditioned for a float32 factorisation to converge quickly
        X, rcond, _ = solve_dense(matrix, rhs, what, "double")
        return X, rcond, 0
    X, refinements = solve_refined(matrix, rhs, (lu, piv), what, refinement_tol, max_refinements)
    return X, rcond, refinements


def solve_refined(matrix: np.ndarray, rhs: np.ndarray, factors, what: str = "BEM system",
                  refinement_tol: float = 1e-12, max_refinements: int = 6):
    """Solve ``matrix @ X = rhs`` (float64) with low-precision LU ``factors`` of ``matrix`` and iterative
    refinement on float64 residuals; returns ``(X, refinements)``."""
    lu, piv = factors
    X = scipy.linalg.lu_solve((lu, piv), rhs.astype(lu.dtype), check_finite=False).astype(float)
    norm_rhs = np.linalg.norm(rhs)
    for k in range(1, max_refinements + 1):
        R = rhs - matrix @ X
        if np.linalg.norm(R) <= refinement_tol * norm_rhs:
            return X, k - 1
        X += scipy.linalg.lu_solve((lu, piv), R.astype(lu.dtype), check_finite=False)
    R = rhs - matrix @ X
    if np.linalg.norm(R) > 1e3 * refinement_tol * norm_rhs:
        raise SingularSystemError(f"the {what} did not converge under iterative refinement "
                                  f"(residual {np.linalg.norm(R) / norm_rhs:.1e}); it is close to singular")
    return X, max_refinements


@dataclass
class BemSolution:
    """Unit solutions of a boundary (one per electrode), and what follows from them.

    Attributes
    ----------
    boundary : WaterBoundary
    sigma_S_per_m : float
    unknowns : (F, n)
        ``x`` for electrode k at 1 V (column k-1): potential on insulating faces,
        ``l q`` on electrode and conductor faces.
    conductor_potentials_V : (n_c, n)
    scale_m : float
        ``l`` of the flux unknowns.
    z_c : (n,) contact impedances (ohm m^2).
    currents_A : (n, n)
        ``C[m, k]``: current leaving electrode m into the water for electrode k at 1 V
        (grounded at infinity in unbounded water).
    emitter : int
    info : dict
    K_correction_S : (n, n) array, optional
        Added to the conductance matrix (not to the surface solution): the
        free-space electrode-edge correction of :mod:`bem.edge_correction`.
    """

    boundary: WaterBoundary
    sigma_S_per_m: float
    unknowns: np.ndarray
    conductor_potentials_V: np.ndarray
    scale_m: float
    z_c: np.ndarray
    currents_A: np.ndarray
    emitter: int
    info: dict = field(default_factory=dict)
    K_correction_S: np.ndarray | None = None

    @property
    def n_electrodes(self) -> int:
        return self.currents_A.shape[0]

    @property
    def K_surface_S(self) -> np.ndarray:
        """The conductance matrix of the surface solution itself (S), without the edge correction:
        the currents the surface current density integrates to."""
        return isolate(self.currents_A) if self.boundary.unbounded else self.currents_A

    @property
    def K_S(self) -> np.ndarray:
        """The isolated sensor's nodal conductance matrix (S), with the edge correction if there is one."""
        return self.K_surface_S if self.K_correction_S is None else self.K_surface_S + self.K_correction_S

    @property
    def conductance(self) -> ConductanceMatrix:
        info = dict(self.info)
        g = ConductanceMatrix(self.K_S, self.emitter, self.sigma_S_per_m, info)
        info.update(asymmetry=g.asymmetry, row_sum_residue=g.row_sum_residue)
        return g

    # ---------------------------------------------------------- surface values
    def isolated_potentials(self, V) -> np.ndarray:
        """Electrode potentials (n,) of the isolated sensor: ``V`` shifted so that the currents sum to zero.

        In a tank nothing changes; in unbounded water the sensor floats to the
        potential that makes its total current vanish (the far field is 0 V).
        """
        V = np.asarray(V, dtype=float).reshape(self.n_electrodes)
        if not self.boundary.unbounded:
            return V
        C = self.currents_A
        return V - (C.sum(axis=0) @ V) / C.sum()

    def surface(self, V) -> tuple[np.ndarray, np.ndarray]:
        """Potential ``u`` (F,) and out-of-water normal derivative ``q`` (F,) for electrode potentials ``V``.

        ``V`` are the isolated sensor's potentials (see :meth:`isolated_potentials`).
        """
        V = self.isolated_potentials(V)
        wb = self.boundary
        x = self.unknowns @ V
        flux = (wb.electrode > 0) | (wb.conductor >= 0)
        q = np.where(flux, x / self.scale_m, 0.0)
        u = np.where(flux, 0.0, x)
        on_e = wb.electrode > 0
        u[on_e] = V[wb.electrode[on_e] - 1] - self.z_c[wb.electrode[on_e] - 1] * self.sigma_S_per_m * q[on_e]
        on_c = wb.conductor >= 0
        if on_c.any():
            W = self.conductor_potentials_V @ V
            u[on_c] = W[wb.conductor[on_c]]
        return u, q

    def electrode_currents_A(self, V) -> np.ndarray:
        """Currents (n,) leaving each electrode into the water for potentials ``V``."""
        return self.K_S @ np.asarray(V, dtype=float)

    def potential_at(self, points_m, V=None) -> np.ndarray:
        """Potential (V) at points (..., 3) in the water; default ``V``: the emitter at 1 V, the rest at 0 V."""
        from .fields import potential_at

        return potential_at(self, points_m, self._default_V(V))

    def current_density_at(self, points_m, V=None) -> np.ndarray:
        """Current density (A/m^2, (..., 3)) at points in the water."""
        from .fields import current_density_at

        return current_density_at(self, points_m, self._default_V(V))

    def _default_V(self, V):
        if V is None:
            V = np.zeros(self.n_electrodes)
            V[self.emitter - 1] = 1.0
        return np.asarray(V, dtype=float)

    def to_pyvista(self, V=None):
        """The surface as ``pyvista.PolyData`` with cell data: potential on insulators and
        electrodes (V), current density into the water (A/m^2, zero on insulators), labels."""
        from .fields import surface_polydata

        return surface_polydata(self, self._default_V(V))


def solve(boundary: WaterBoundary, sigma_S_per_m: float, contact_impedance_ohm_m2=None,
          emitter: int | None = None, precision: str = "mixed") -> BemSolution:
    """Assemble, factorise and solve the BEM on ``boundary`` for every electrode at 1 V in turn
    (``precision``: see :func:`solve_dense`)."""
    t0 = time.perf_counter()
    n = boundary.n_electrodes
    emitter = n if emitter is None else int(emitter)
    if not 1 <= emitter <= n:
        raise BoundaryError(f"emitter {emitter} is not an electrode (1..{n})")
    system = assemble_system(boundary, sigma_S_per_m, contact_impedance_ohm_m2)
    t1 = time.perf_counter()
    sol, rcond, refinements = solve_dense(system.matrix, system.rhs, precision=precision)
    t2 = time.perf_counter()
    return _finish(boundary, sigma_S_per_m, system, sol, emitter,
                   {"assembly_s": t1 - t0, "solve_s": t2 - t1, "rcond": rcond, "refinements": refinements})


def _finish(boundary, sigma, system: BemSystem, sol, emitter, timing) -> BemSolution:
    n_f = boundary.n_triangles
    if not np.all(np.isfinite(sol)):
        raise SingularSystemError("the BEM solution is not finite: the system is singular")
    x, W = sol[:n_f], sol[n_f:]
    n = boundary.n_electrodes
    areas = 0.5 * np.linalg.norm(np.cross(boundary.triangles_m[:, 1] - boundary.triangles_m[:, 0],
                                          boundary.triangles_m[:, 2] - boundary.triangles_m[:, 0]), axis=1)
    on_e = boundary.electrode > 0
    C = np.zeros((n, n))
    np.add.at(C, boundary.electrode[on_e] - 1, (sigma / system.scale_m) * areas[on_e, None] * x[on_e])
    info = {"model": "bem", "triangles": int(n_f), "unknowns": int(n_f + system.n_conductors),
            "unbounded": bool(boundary.unbounded), **timing}
    return BemSolution(boundary, float(sigma), x, W, system.scale_m, system.z_c, C, emitter, info)


def check_object_materials(objects) -> None:
    """The BEM models objects as perfect insulators (0 S/m) or perfect conductors (inf); refuse others."""
    for i, obj in enumerate(objects, start=1):
        if not (obj.is_insulating or obj.is_conducting):
            raise ValueError(f"object_{i} ({obj.label}) has conductivity {obj.conductivity_S_per_m} S/m: the BEM "
                             "handles insulating (0) or perfectly conducting (inf) objects only")


def solve_scene(scene, sigma_S_per_m: float, contact_impedance_ohm_m2=None, edge_length_m=None,
                axisymmetric: bool | None = None, edge_correction: bool = True, **mesh_options) -> BemSolution:
    """Mesh a :class:`meshes.scene.Scene` (or take a sensor ``LabelledMesh`` in unbounded water) and solve it.

    ``axisymmetric``: use the axisymmetric reduction (:mod:`bem.axisymmetric`);
    default: for a scene whose sensor is alone in unbounded water (meshed by
    ``mesh_sensor``), not for a user's mesh.
    ``edge_correction``: add the sensor mesh's free-space electrode-edge error
    to the conductance matrix (:mod:`bem.edge_correction`; scenes only, not a
    user's mesh). ``info["edge_correction_max_relative"]`` says how large it was.
    """
    from meshes.labelled_mesh import LabelledMesh

    t0 = time.perf_counter()
    if isinstance(scene, LabelledMesh):
        boundary = WaterBoundary.from_meshes(scene)
        emitter = None
        t_mesh = time.perf_counter() - t0
    else:
        from meshes.scene_mesh import mesh_scene

        check_object_materials(scene.objects)
        sm = mesh_scene(scene, edge_length_m, **mesh_options)
        emitter = scene.sensor.emitter if scene.sensor is not None else 1
        boundary = WaterBoundary.from_meshes(
            sm.sensor_in_tank, sm.tank, sm.objects, tuple(o.is_conducting for o in scene.objects),
            emitter=emitter)
        t_mesh = time.perf_counter() - t0
        if scene.sensor is None:  # electrodes on the tank only: the plain surface solve
            solution = solve(boundary, sigma_S_per_m, contact_impedance_ohm_m2, emitter)
            solution.info["mesh_s"] = t_mesh
            solution.info["seconds"] = time.perf_counter() - t0
            if contact_impedance_ohm_m2 is not None:
                solution.info["contact_impedance_ohm_m2"] = solution.z_c.tolist()
            return solution
    from .axisymmetric import is_axisymmetric_sensor, solve_axisymmetric

    if axisymmetric is None:
        axisymmetric = not isinstance(scene, LabelledMesh) and not scene.objects and scene.tank is None
    # the ring classes are found about the x axis: take the sensor frame for a scene (same faces, same order)
    own_frame = boundary if isinstance(scene, LabelledMesh) else WaterBoundary.from_meshes(sm.sensor, emitter=emitter)
    solved_axisymmetric = axisymmetric and is_axisymmetric_sensor(own_frame)
    if solved_axisymmetric:
        # 16 collocation points per ring class: K within 6e-6 of all of them (angels-4), 25 % faster
        solution = solve_axisymmetric(own_frame, sigma_S_per_m, contact_impedance_ohm_m2, emitter,
                                      targets_per_class=AXISYMMETRIC_TARGETS_PER_CLASS)
        solution.boundary = boundary   # unbounded water: the same unknowns at the sensor's pose
    else:
        solution = solve(boundary, sigma_S_per_m, contact_impedance_ohm_m2, emitter)
    solution.info["mesh_s"] = t_mesh
    if edge_correction and not isinstance(scene, LabelledMesh) and not scene.electrodes:
        from .edge_correction import free_space_correction

        t1 = time.perf_counter()
        free_K = solution.K_S if solved_axisymmetric and not scene.objects and scene.tank is None else None
        dK = free_space_correction(scene.sensor, sigma_S_per_m, contact_impedance_ohm_m2, sm.sensor,
                                   surface_K_S=free_K)
        solution.info["edge_correction_max_relative"] = float(np.max(np.abs(dK)) / np.max(np.abs(solution.K_S)))
        solution.K_correction_S = dK
        solution.info["edge_correction_s"] = time.perf_counter() - t1
    solution.info["seconds"] = time.perf_counter() - t0
    if contact_impedance_ohm_m2 is not None:
        solution.info["contact_impedance_ohm_m2"] = solution.z_c.tolist()
    return solution


def conductance_matrix(scene, sigma_S_per_m: float, contact_impedance_ohm_m2=None,
                       edge_length_m=None, edge_correction: bool = True, **mesh_options) -> ConductanceMatrix:
    """The BEM conductance matrix of a scene (sensor at its pose, optional tank and objects).

    Parameters
    ----------
    scene : meshes.scene.Scene or meshes.labelled_mesh.LabelledMesh
        A scene, or a closed labelled sensor mesh alone in unbounded water.
    sigma_S_per_m : float
        Water conductivity (S/m).
    contact_impedance_ohm_m2 : float or sequence, optional
        Contact impedance of every electrode, or one per electrode (ohm m^2).
    edge_length_m : float, optional
        Sensor mesh edge length far from electrode edges (default: the mesher's).
    edge_correction : bool
        Add the free-space electrode-edge correction (:mod:`bem.edge_correction`,
        scenes only): the default mesh is then within about 0.1 % of the
        mesh-converged matrix instead of about 0.5 %.

    Returns
    -------
    ConductanceMatrix
        ``info`` holds ``triangles``, ``seconds``, ``asymmetry``, ``row_sum_residue``.
    """
    return solve_scene(scene, sigma_S_per_m, contact_impedance_ohm_m2, edge_length_m,
                       edge_correction=edge_correction, **mesh_options).conductance
