"""Solving a scene: mesh it, solve the water boundary, correct the electrode edges.

:func:`solve_scene` meshes a :class:`electrosense.meshes.scene.Scene` (or takes a user's
sensor mesh), solves it by the axisymmetric reduction when the sensor is
alone in unbounded water (:mod:`.axisymmetric`; a sensor with sectors by
azimuthal modes, :mod:`.symmetric`), else by the full
collocation (:func:`electrosense.bem.solution.solve`), and corrects K for the
electrode edges: the free-space correction (:mod:`.edge_correction`) carried
into the scene (:func:`.edge_correction.scene_correction`).
:func:`conductance_matrix` is its :class:`ConductanceMatrix`.

Example
-------
>>> from electrosense.meshes import Scene, preset
>>> from electrosense.bem.solve import conductance_matrix
>>> g = conductance_matrix(Scene(preset("angels-2")), sigma_S_per_m=1.0)
>>> bool(g.S_S[0, 0] > 0 and g.asymmetry < 1e-6)
True
"""
from __future__ import annotations

import time

import numpy as np

from electrosense.bem.axisymmetric import AXISYMMETRIC_TARGETS_PER_CLASS, is_axisymmetric_sensor, solve_axisymmetric
from electrosense.bem.boundary_conditions import WaterBoundary
from electrosense.bem.conductance import ConductanceMatrix
from electrosense.bem.edge_correction import scene_correction
from electrosense.bem.linear_solve import SingularSystemError, factorise, solve_refined
from electrosense.bem.solution import BemSolution, solve
from electrosense.bem.symmetric import solve_symmetric

__all__ = ["BemSolution", "solve", "solve_scene", "conductance_matrix", "factorise", "solve_refined",
           "SingularSystemError", "check_object_materials"]


def check_object_materials(objects) -> None:
    """The BEM models objects as perfect insulators (0 S/m) or perfect conductors (inf); refuse others."""
    for i, obj in enumerate(objects, start=1):
        if not (obj.is_insulating or obj.is_conducting):
            raise ValueError(f"object_{i} ({obj.label}) has conductivity {obj.conductivity_S_per_m} S/m: the BEM "
                             "handles insulating (0) or perfectly conducting (inf) objects only")


def solve_scene(scene, sigma_S_per_m: float, contact_impedance_ohm_m2=None, edge_length_m=None,
                axisymmetric: bool | None = None, edge_correction: bool = True, **mesh_options) -> BemSolution:
    """Mesh a :class:`electrosense.meshes.scene.Scene` (or take a sensor ``LabelledMesh`` in unbounded water) and solve it.

    ``axisymmetric``: use the axisymmetric reduction (:mod:`electrosense.bem.axisymmetric`);
    default: for a scene whose sensor is alone in unbounded water (meshed by
    ``mesh_sensor``), not for a user's mesh.
    ``edge_correction``: correct the conductance matrix for the sensor mesh's
    electrode-edge error, measured in free space and carried into the scene
    (:func:`electrosense.bem.edge_correction.scene_correction`; scenes only, not a
    user's mesh). ``info["edge_correction_max_relative"]`` says how large it was.
    """
    from electrosense.meshes.labelled_mesh import LabelledMesh

    t0 = time.perf_counter()
    if isinstance(scene, LabelledMesh):
        boundary = WaterBoundary.from_meshes(scene)
        emitter = None
        t_mesh = time.perf_counter() - t0
    else:
        from electrosense.meshes.scene_mesh import mesh_scene

        check_object_materials(scene.objects)
        sm = mesh_scene(scene, edge_length_m, **mesh_options)
        emitter = scene.sensor.emitter if scene.sensor is not None else 1
        touching = scene.sensor is not None and scene.sensor.sectors_touch
        boundary = WaterBoundary.from_meshes(
            sm.sensor_in_tank, sm.tank, sm.objects + sm.electrode_bodies,
            tuple(o.is_conducting for o in scene.objects), emitter=emitter, allow_touching=touching)
        t_mesh = time.perf_counter() - t0
        if scene.sensor is None:  # electrodes on the tank only: the plain surface solve
            solution = solve(boundary, sigma_S_per_m, contact_impedance_ohm_m2, emitter)
            solution.info["mesh_s"] = t_mesh
            solution.info["seconds"] = time.perf_counter() - t0
            if contact_impedance_ohm_m2 is not None:
                solution.info["contact_impedance_ohm_m2"] = solution.z_c.tolist()
            return solution
    if axisymmetric is None:
        axisymmetric = not isinstance(scene, LabelledMesh) and not scene.objects and scene.tank is None
    # the ring classes are found about the x axis: take the sensor frame for a scene (same faces, same order)
    own_frame = boundary if isinstance(scene, LabelledMesh) else WaterBoundary.from_meshes(
        sm.sensor, emitter=emitter, allow_touching=touching)
    sectors = not isinstance(scene, LabelledMesh) and scene.sensor.has_sectors
    solved_axisymmetric = axisymmetric and not sectors and is_axisymmetric_sensor(own_frame)
    if axisymmetric and sectors:   # rotationally symmetric, not axisymmetric: mode by mode (bem/symmetric.py)
        from electrosense.meshes.sector_mesh import block_symmetry

        order, mirror = block_symmetry(scene.sensor)
        solution = solve_symmetric(own_frame, sigma_S_per_m, contact_impedance_ohm_m2, emitter, order=order,
                                   mirror=mirror)
        solution.boundary = boundary
    elif solved_axisymmetric:
        # 16 collocation points per ring class: K within 6e-6 of all of them (angels-4), 25 % faster
        solution = solve_axisymmetric(own_frame, sigma_S_per_m, contact_impedance_ohm_m2, emitter,
                                      targets_per_class=AXISYMMETRIC_TARGETS_PER_CLASS)
        solution.boundary = boundary   # unbounded water: the same unknowns at the sensor's pose
    else:
        solution = solve(boundary, sigma_S_per_m, contact_impedance_ohm_m2, emitter)
    solution.info["mesh_s"] = t_mesh
    if edge_correction and not isinstance(scene, LabelledMesh) and not scene.electrodes:
        t1 = time.perf_counter()
        free_K = solution.K_S if solved_axisymmetric and not scene.objects and scene.tank is None else None
        if sectors and not scene.objects and scene.tank is None:
            free_K = solution.K_S
        dK = scene_correction(scene.sensor, sigma_S_per_m, contact_impedance_ohm_m2, sm.sensor, solution.K_S,
                              surface_K_S=free_K, mesh_options=_sensor_options(mesh_options, edge_length_m))
        solution.info["edge_correction_max_relative"] = float(np.max(np.abs(dK)) / np.max(np.abs(solution.K_S)))
        solution.K_correction_S = dK
        solution.info["edge_correction_s"] = time.perf_counter() - t1
    solution.info["seconds"] = time.perf_counter() - t0
    if contact_impedance_ohm_m2 is not None:
        solution.info["contact_impedance_ohm_m2"] = solution.z_c.tolist()
    return solution


def _sensor_options(mesh_options: dict, edge_length_m) -> dict:
    """The options of :func:`electrosense.meshes.scene_mesh.mesh_scene` that go to the sensor's mesh."""
    scene_only = {"tank_edge_length_m", "tank_grading", "tank_focus_m", "object_edge_length_m", "check"}
    return {**{k: v for k, v in mesh_options.items() if k not in scene_only}, "edge_length_m": edge_length_m}


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
        Add the free-space electrode-edge correction (:mod:`electrosense.bem.edge_correction`,
        scenes only): the default mesh is then within about 0.1 % of the
        mesh-converged matrix instead of about 0.5 %.

    Returns
    -------
    ConductanceMatrix
        ``info`` holds ``triangles``, ``seconds``, ``asymmetry``, ``row_sum_residue``.
    """
    return solve_scene(scene, sigma_S_per_m, contact_impedance_ohm_m2, edge_length_m,
                       edge_correction=edge_correction, **mesh_options).conductance
