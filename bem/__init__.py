"""bem: collocation boundary-element solver of steady conduction around a sensor.

Public API
----------
conductance_matrix(scene, sigma_S_per_m, contact_impedance_ohm_m2=None, edge_length_m=None)
    The isolated sensor's nodal conductance matrix (:class:`ConductanceMatrix`).
solve_scene(scene, ...) / solve(boundary, ...)
    The unit surface solutions (:class:`BemSolution`): currents for any
    electrode potentials, ``potential_at``, ``current_density_at``, ``to_pyvista``.
PoseSweep(sensor, tank=None, objects=(), sigma_S_per_m=...)
    Many poses of one sensor in one tank, reusing the pose-invariant blocks.
single_layer, double_layer
    Dense collocation matrices of the Laplace layer potentials on flat triangles.

A sensor alone in unbounded water is solved by the axisymmetric reduction
(:mod:`electrosense.bem.axisymmetric`, within 1e-4 of the full collocation).
"""
from electrosense.bem.boundary_conditions import BoundaryError, WaterBoundary
from electrosense.bem.conductance import ConductanceMatrix, K_from_S, S_from_K, isolate
from electrosense.bem.memory import MemoryRefusal
from electrosense.bem.solve import BemSolution, SingularSystemError, conductance_matrix, solve, solve_scene

_LAZY = {
    "single_layer": "operators", "double_layer": "operators",
    "potential_at": "fields", "current_density_at": "fields", "plane_points": "fields",
    "PoseSweep": "sweep",
}

__all__ = ["ConductanceMatrix", "K_from_S", "S_from_K", "isolate", "BoundaryError", "WaterBoundary",
           "MemoryRefusal", "BemSolution", "SingularSystemError", "conductance_matrix", "solve", "solve_scene",
           *_LAZY]


def __getattr__(name):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'bem' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
