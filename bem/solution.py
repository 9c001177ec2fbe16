"""The unit solutions of a water boundary, one per electrode at 1 V, and what follows from them.

:func:`solve` assembles the collocation system of a :class:`WaterBoundary`
(:mod:`.system`), solves it for every electrode at 1 V in turn
(:mod:`.linear_solve`) and returns a :class:`BemSolution`: the conductance
matrix, surface values, fields.

Currents. The current leaving electrode ``m`` into the water is
``sigma * sum_j a_j q_j`` over its faces. In a closed tank the currents of
the unit solutions form the isolated ``K`` directly. In unbounded water they
form the grounded ``C`` (far field at 0 V), and the isolated sensor's ``K``
is ``electrosense.bem.conductance.isolate(C)``: the sensor floats to the common potential
at which its currents sum to zero.

Example
-------
>>> from electrosense.meshes import preset
>>> from electrosense.meshes.sensor_mesh import mesh_sensor
>>> from electrosense.bem.boundary_conditions import WaterBoundary
>>> wb = WaterBoundary.from_meshes(mesh_sensor(preset("angels-2"), edge_length_m=0.02))
>>> s = solve(wb, sigma_S_per_m=1.0)
>>> bool(abs(s.K_S.sum(axis=1)).max() < 1e-10 * abs(s.K_S).max())
True
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from electrosense.bem.boundary_conditions import BoundaryError, WaterBoundary
from electrosense.bem.conductance import ConductanceMatrix, isolate
from electrosense.bem.fields import current_density_at, potential_at, surface_polydata
from electrosense.bem.linear_solve import SingularSystemError, solve_dense
from electrosense.bem.system import BemSystem, assemble_system

__all__ = ["BemSolution", "solve", "unit_solutions"]


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
        free-space electrode-edge correction of :mod:`electrosense.bem.edge_correction`.
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
        return potential_at(self, points_m, self._default_V(V))

    def current_density_at(self, points_m, V=None) -> np.ndarray:
        """Current density (A/m^2, (..., 3)) at points in the water."""
        return current_density_at(self, points_m, self._default_V(V))

    def _default_V(self, V):
        if V is None:
            V = np.zeros(self.n_electrodes)
            V[self.emitter - 1] = 1.0
        return np.asarray(V, dtype=float)

    def to_pyvista(self, V=None):
        """The surface as ``pyvista.PolyData`` with cell data: potential on insulators and
        electrodes (V), current density into the water (A/m^2, zero on insulators), labels."""
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
    return unit_solutions(boundary, sigma_S_per_m, system, sol, emitter,
                   {"assembly_s": t1 - t0, "solve_s": t2 - t1, "rcond": rcond, "refinements": refinements})


def unit_solutions(boundary, sigma, system: BemSystem, sol, emitter, timing) -> BemSolution:
    """The :class:`BemSolution` of the solved system ``sol`` (unknowns of every unit solution, then conductor
    potentials): electrode currents from the flux unknowns."""
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
