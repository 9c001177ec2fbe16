"""Ring-element BEM on the meridian (bem.meridian) and the edge correction it feeds (bem.edge_correction).

Checked against closed forms (ring kernels against direct azimuthal quadrature,
a sphere's capacitance, a contact impedance in series), against its own
refinement (observed order 2) and against the surface BEM refined far past
its default, which is a different discretisation of the same problem.
"""
import numpy as np
import pytest

from electrosense.bem.meridian import (
    converged_conductance,
    layer_operators,
    meridian_conductance,
    mesh_meridian,
    ring_double_layer,
    ring_single_layer,
)
from electrosense.meshes import preset
from electrosense.meshes.sensor import Electrode, SensorDescription


def _sphere(a=0.01):
    """A sphere as a sensor: two hemispherical electrodes 2e-7 a apart (length a hair above 2a)."""
    half = a * (1 + 1e-9)
    return SensorDescription(name="sphere", radius_m=a, length_m=2 * half,
                             electrodes=(Electrode("cap", 1e-7 * a, half), Electrode("cap", -half, -1e-7 * a)))


@pytest.mark.parametrize("target", [(0.013, 0.007), (0.0041, 0.0108), (0.2, 0.0)])
def test_ring_kernels_match_azimuthal_quadrature(target):
    x, r = target
    xs, rs, nx, nr = 0.004, 0.011, 0.6, 0.8
    phi = np.linspace(0, 2 * np.pi, 400001)[:-1]
    R = np.sqrt(r**2 + rs**2 - 2 * r * rs * np.cos(phi) + (x - xs) ** 2)
    single = np.mean(rs / (4 * np.pi * R)) * 2 * np.pi
    dot = nr * (r * np.cos(phi) - rs) + nx * (x - xs)          # (x - y) . n_y
    double = np.mean(rs * dot / (4 * np.pi * R**3)) * 2 * np.pi
    assert ring_single_layer(x, r, xs, rs) == pytest.approx(single, rel=1e-9)
    assert ring_double_layer(x, r, xs, rs, nx, nr) == pytest.approx(double, rel=1e-8)


def test_sphere_capacitance_and_contact_impedance():
    a, sigma, z = 0.01, 0.05, 0.02
    s = _sphere(a)
    mesh = mesh_meridian(s, a / 8, a / 8, 1.05)
    C = meridian_conductance(s, sigma, mesh=mesh, grounded=True).K_S
    assert C.sum() == pytest.approx(4 * np.pi * sigma * a, rel=1e-6)      # both halves at 1 V
    Cz = meridian_conductance(s, sigma, z, mesh=mesh, grounded=True).K_S
    assert 1 / Cz.sum() == pytest.approx(1 / (4 * np.pi * sigma * a) + z / (4 * np.pi * a**2), rel=1e-6)


def test_conventions_symmetric_zero_row_sums_positive_diagonal():
    g = meridian_conductance(preset("angels-4"), 0.0354)
    K = g.K_S
    assert np.allclose(K, K.T, rtol=0, atol=1e-12 * np.abs(K).max())
    assert np.abs(K.sum(axis=1)).max() < 1e-12 * np.abs(K).max()
    assert np.all(np.diag(K) > 0) and np.all(K[~np.eye(4, dtype=bool)] < 0)
    assert np.all(np.linalg.eigvalsh(K)[1:] > 0)
    assert g.emitter == 4 and g.S_S.shape == (3, 3)


def test_observed_order_two_and_a_converged_limit():
    g = converged_conductance(preset("angels-2"), 1.0, refinements=(0.5, 1, 2))
    order = np.asarray(g.info["observed_order"])
    assert np.all(np.abs(order - 2) < 0.15)
    assert g.info["finest_departure"] < 2e-4


def test_agrees_with_the_refined_surface_bem():
    """The surface BEM on a mesh 4x finer than the default (axisymmetric reduction), angels-2:
    0.07 % below its own Richardson limit, which the ring elements match to 0.01 %."""
    from electrosense.bem.axisymmetric import solve_axisymmetric
    from electrosense.bem.boundary_conditions import WaterBoundary
    from electrosense.meshes.sensor_mesh import default_edge_length_m, mesh_sensor

    s = preset("angels-2")
    h0 = default_edge_length_m(s)
    surface = mesh_sensor(s, edge_length_m=h0 / 4, grading=1 + 0.15 / 4)
    S_surface = solve_axisymmetric(WaterBoundary.from_meshes(surface, emitter=s.emitter), 1.0, None, s.emitter,
                                   targets_per_class=4).K_S[0, 0]
    S_ring = meridian_conductance(s, 1.0).K_S[0, 0]
    assert 0 < S_ring / S_surface - 1 < 2e-3


def test_refuses_bad_meshes():
    with pytest.raises(ValueError, match="h_edge_m"):
        mesh_meridian(preset("angels-2"), 0.001, 0.01)
    with pytest.raises(ValueError, match="sigma_S_per_m"):
        meridian_conductance(preset("angels-2"), -1.0)


# ---------------------------------------------------------------- edge correction
def test_edge_correction_brings_the_default_mesh_to_the_converged_matrix():
    from electrosense.bem.solve import conductance_matrix
    from electrosense.meshes import Scene

    s = preset("angels-4")
    reference = converged_conductance(s, 1.0, refinements=(0.5, 1, 2)).S_S
    raw = conductance_matrix(Scene(s), 1.0, edge_correction=False)
    corrected = conductance_matrix(Scene(s), 1.0)
    raw_error = np.abs(raw.S_S / reference - 1).max()
    corrected_error = np.abs(corrected.S_S / reference - 1).max()
    assert 2e-3 < raw_error < 1e-2          # the edge singularity: the default surface mesh is ~0.5 % low
    assert corrected_error < 3e-4
    assert corrected.info["edge_correction_max_relative"] > 1e-3
    K = corrected.K_S
    assert np.abs(K.sum(axis=1)).max() < 1e-9 * np.abs(K).max()
    assert np.allclose(K, K.T, atol=1e-9 * np.abs(K).max())


def test_edge_correction_is_the_same_in_a_sweep_and_in_a_scene():
    from electrosense.bem.solve import conductance_matrix
    from electrosense.bem.sweep import PoseSweep
    from electrosense.meshes import Pose, Scene, Tank

    s, tank = preset("angels-2"), Tank((0.6, 0.5, 0.4))
    pose = Pose(0.05, 0.02, 0.0, 0.3)
    scene = conductance_matrix(Scene(s, pose, tank), 0.05, tank_focus_m=None)
    sweep = PoseSweep(s, tank, sigma_S_per_m=0.05, focus_m=None).conductance([pose.as_array()])
    assert sweep.K_S[0] == pytest.approx(scene.K_S, rel=1e-4)   # low-rank coupling, float32 factors
    raw = PoseSweep(s, tank, sigma_S_per_m=0.05, edge_correction=False).conductance([pose.as_array()])
    shift = sweep.K_S[0, 0, 0] / raw.K_S[0, 0, 0] - 1
    assert 1e-3 < shift < 1e-2


def test_contact_impedance_removes_most_of_the_edge_error():
    """Behind a contact impedance the current density is no longer singular at the electrode edges (it is
    smoothed over the length z_c sigma), so the surface mesh's own error (and with it the correction) shrinks."""
    from electrosense.bem.edge_correction import free_space_correction
    from electrosense.meshes.sensor_mesh import mesh_sensor

    s = preset("angels-2")
    mesh = mesh_sensor(s)
    bare = free_space_correction(s, 1.0, None, mesh)[0, 0]
    smoothed = [free_space_correction(s, 1.0, z, mesh)[0, 0] for z in (1e-5, 1e-4, 1e-3)]   # z sigma: 0.01-1 mm
    assert bare > smoothed[0] > smoothed[1] > smoothed[2]
    assert bare > 20 * abs(smoothed[2])


@pytest.mark.slow
def test_edge_correction_carries_over_to_a_sensor_near_a_wall():
    """A five-electrode sensor that is not a preset, tip 1 cm from a wall and turned: refining the sensor
    mesh by sqrt 2 moves the corrected S by ~0.015 %, the surface solution's own S by ~0.16 %
    (and in free space the correction takes the default mesh from ~0.46 % to ~0.01 % of converged)."""
    from electrosense.bem.solve import conductance_matrix
    from electrosense.meshes import Pose, Scene, Tank
    from electrosense.meshes.sensor_mesh import default_edge_length_m

    s = SensorDescription(name="five", radius_m=0.008, length_m=0.15, electrodes=(
        Electrode("cap", 0.068, 0.075), Electrode("ring", 0.03, 0.04), Electrode("ring", -0.005, 0.005),
        Electrode("ring", -0.04, -0.03), Electrode("cap", -0.075, -0.068)))
    reference = converged_conductance(s, 0.05, refinements=(0.5, 1, 2)).S_S
    assert np.abs(conductance_matrix(Scene(s), 0.05).S_S / reference - 1).max() < 3e-4
    scene = Scene(s, Pose(0.3 - 0.075 - 0.01, 0.05, 0.0, 0.2), Tank((0.6, 0.5, 0.4)))
    finer = dict(edge_length_m=default_edge_length_m(s) / np.sqrt(2), grading=1 + 0.15 / np.sqrt(2))
    for correct, low, high in ((True, 0.0, 5e-4), (False, 1e-3, 1e-2)):
        default = conductance_matrix(scene, 0.05, edge_correction=correct).S_S
        refined = conductance_matrix(scene, 0.05, edge_correction=correct, **finer).S_S
        assert low <= np.abs(default / refined - 1).max() < high


def test_operators_assembled_once_serve_every_contact_impedance():
    sensor = preset("angels-2")
    mesh = mesh_meridian(sensor)
    operators = layer_operators(mesh)
    for z in (None, 1e-3, [1e-4, 1e-2]):
        fresh = meridian_conductance(sensor, 0.05, z, mesh=mesh).K_S
        again = meridian_conductance(sensor, 0.05, z, mesh=mesh, operators=operators).K_S
        assert np.array_equal(fresh, again)


def test_a_wall_across_the_axis_by_its_image():
    """The wall's image on ring elements: far away it changes nothing, 5 mm from the tip it lowers the tip's
    conductance (an insulating wall in the current's way), and it is refused where it would cut the sensor."""
    sensor = preset("angels-2")
    tip = 0.5 * sensor.length_m
    free = meridian_conductance(sensor, 1.0).K_S
    far = meridian_conductance(sensor, 1.0, wall_x_m=tip + 20.0).K_S
    assert np.abs(far / free - 1).max() < 1e-6                  # the wall's effect falls as (L / d)^3
    near = meridian_conductance(sensor, 1.0, wall_x_m=tip + 0.005).K_S
    assert np.abs(near.sum(axis=1)).max() < 1e-9 * np.abs(near).max()
    assert np.allclose(near, near.T, rtol=2e-3, atol=0)         # collocation: symmetric to the mesh's error
    assert near[0, 0] < free[0, 0]                               # an insulating wall blocks the tip's current
    with pytest.raises(ValueError, match="beyond the sensor's head tip"):
        meridian_conductance(sensor, 1.0, wall_x_m=tip - 0.001)


def test_the_edge_correction_scaled_into_a_scene_beats_a_constant_one():
    """A sensor's tip 5 mm from a wall, square on: ring elements with the wall's image against the surface BEM
    (the sensor and its mirror image) on a coarse sensor mesh. The wall changes K by 18 %; the correction scaled
    into the scene (the BEM's) leaves about half the constant one's error, and a third on the mutual conductances
    (esense study edge_correction_wall: 0.015 % against 0.062 % on the default mesh)."""
    from electrosense.bem.edge_correction import free_space_correction_with_K, scaled_to_scene
    from electrosense.meshes.sensor_mesh import default_edge_length_m, mesh_sensor
    from electrosense.validation.studies.edge_correction_wall import errors, surface_K_facing_wall

    sensor = preset("angels-4")
    wall = 0.5 * sensor.length_m + 0.005
    reference = meridian_conductance(sensor, 1.0, wall_x_m=wall).K_S
    mesh = mesh_sensor(sensor, 2.0 * default_edge_length_m(sensor))
    dK, free_K = free_space_correction_with_K(sensor, 1.0, None, mesh, disk_cache=False)
    K = surface_K_facing_wall(mesh, 1.0, wall)
    scaled = scaled_to_scene(dK, free_K, K)
    assert np.abs(scaled.sum(axis=1)).max() < 1e-12 * np.abs(K).max()
    assert np.allclose(scaled, scaled.T)
    assert np.allclose(scaled_to_scene(dK, free_K, free_K), dK)   # free space: the correction itself
    none, constant, scaled_error = (errors(k, reference, sensor.emitter) for k in (K, K + dK, K + scaled))
    assert none[0] > 1.0                                          # the coarse mesh: ~1.2 % low
    assert scaled_error[0] < 0.7 * constant[0] and scaled_error[1] < 0.4 * constant[1]
    assert scaled_error[0] < 0.07


def test_a_wall_beside_operators_assembled_already_is_refused():
    sensor = preset("angels-2")
    mesh = mesh_meridian(sensor)
    with pytest.raises(ValueError, match="wall_x_m"):
        meridian_conductance(sensor, 1.0, mesh=mesh, operators=layer_operators(mesh),
                             wall_x_m=0.5 * sensor.length_m + 0.01)
