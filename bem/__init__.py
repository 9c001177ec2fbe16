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
"""
from .conductance import ConductanceMatrix, K_from_S, S_from_K, isolate
from .boundary_conditions import BoundaryError, WaterBoundary
from .memory import MemoryRefusal
from .fields import current_density_at, plane_points, potential_at
from .operators import double_layer, single_layer
from .solve import BemSolution, SingularSystemError, conductance_matrix, solve, solve_scene

__all__ = [
    "ConductanceMatrix", "K_from_S", "S_from_K", "isolate",
    "BoundaryError", "WaterBoundary", "MemoryRefusal", "single_layer", "double_layer",
    "BemSolution", "SingularSystemError", "conductance_matrix", "solve", "solve_scene",
    "potential_at", "current_density_at", "plane_points",
]

try:  # the pose sweep lands after the single-scene solver
    from .sweep import PoseSweep  # noqa: F401

    __all__.append("PoseSweep")
except ImportError:  # pragma: no cover
    pass
