"""BEM verification against closed forms and invariants (small meshes, fast)."""
import functools

import numpy as np
import pytest
import trimesh

from electrosense.bem.boundary_conditions import WaterBoundary
from electrosense.bem.closed_forms import two_sphere_resistance_ohm
from electrosense.bem.conductance import isolate
from electrosense.bem.solve import solve
from electrosense.meshes.labelled_mesh import LabelledMesh, concatenate
from electrosense.meshes.pose import Pose


def sphere_mesh(radius_m, centre_m=(0, 0, 0), electrode=1, subdivisions=3, region="sensor"):
    """Icosphere scaled so that the polyhedron has the sphere's volume (normals outwards)."""
    s = trimesh.creation.icosphere(subdivisions)
    scale = radius_m * (4 / 3 * np.pi / s.volume) ** (1 / 3)
    return LabelledMesh(s.vertices * scale + np.asarray(centre_m, float), s.faces,
                        np.full(len(s.faces), electrode), None, (region,))


@functools.lru_cache(maxsize=None)
def two_spheres(d, subdivisions=3, sigma=1.0, z_c=None):
    mesh = concatenate([sphere_mesh(0.01, (0, 0, 0), 1, subdivisions), sphere_mesh(0.01, (d, 0, 0), 2, subdivisions)])
    return solve(WaterBoundary.from_meshes(mesh), sigma, z_c)


def test_series_reference_values():
    # the values quoted in the project's notes
    assert two_sphere_resistance_ohm(0.01, 0.10) == pytest.approx(14.32233, abs=1e-5)
    assert two_sphere_resistance_ohm(0.01, 0.03) == pytest.approx(10.36590, abs=1e-5)


@pytest.mark.parametrize("d", [0.10, 0.03])
def test_two_spheres_against_the_exact_series(d):
    K = two_spheres(d).K_S
    assert 1 / K[0, 0] == pytest.approx(two_sphere_resistance_ohm(0.01, d), rel=5e-3)


def test_observed_order_of_convergence():
    exact = two_sphere_resistance_ohm(0.01, 0.10)
    errors = [abs(1 / two_spheres(0.10, s).K_S[0, 0] - exact) for s in (1, 2, 3)]
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))   # h halves per subdivision
    # P0 collocation on flat facets: O(h^2), reached on the finer pair (the coarsest mesh has 80 faces a sphere)
    assert 1.8 < orders[-1] < 2.4 and orders[0] > 1.4, orders


def test_single_sphere_capacitance():
    # one sphere far from the other: grounded self conductance -> 4 pi sigma a
    sol = two_spheres(1.0, 2)
    C = sol.currents_A
    assert C[0, 0] == pytest.approx(4 * np.pi * 0.01 * (1 + 0.01**2 / 1.0**2), rel=3e-3)   # c11 = a (1 + a^2/d^2 + ...)


def test_K_symmetric_with_zero_row_sums():
    g = two_spheres(0.03).conductance
    assert g.asymmetry < 1e-3
    assert g.row_sum_residue < 1e-12
    assert np.all(np.linalg.eigvalsh(0.5 * (g.K_S + g.K_S.T)) > -1e-12)


def test_independent_of_rotation_and_translation():
    mesh = concatenate([sphere_mesh(0.01, (0, 0, 0), 1, 2), sphere_mesh(0.01, (0.04, 0, 0), 2, 2),
                        sphere_mesh(0.008, (-0.03, 0.01, 0), 3, 2)])
    K0 = solve(WaterBoundary.from_meshes(mesh), 1.0).K_S
    moved = mesh.transformed(Pose(0.3, -0.2, 0.1, 1.1))
    K1 = solve(WaterBoundary.from_meshes(moved), 1.0).K_S
    np.testing.assert_allclose(K1, K0, rtol=1e-9, atol=1e-12 * np.abs(K0).max())


def test_contact_impedance_adds_the_series_resistance():
    z_c = 0.002  # ohm m^2
    a = 0.01
    R0 = 1 / two_spheres(0.10, 3).K_S[0, 0]
    Rz = 1 / two_spheres(0.10, 3, 1.0, z_c).K_S[0, 0]
    # two electrodes in series, each z_c over its area (uniform density on a sphere to O(a/d))
    assert Rz - R0 == pytest.approx(2 * z_c / (4 * np.pi * a**2), rel=1e-2)


def test_per_electrode_contact_impedance_and_sigma_scaling():
    sol = two_spheres(0.10, 2, 2.0, (0.0, 0.004))
    R = 1 / sol.K_S[0, 0]
    R0 = 1 / two_spheres(0.10, 2, 2.0).K_S[0, 0]
    assert R - R0 == pytest.approx(0.004 / (4 * np.pi * 0.01**2), rel=1e-2)
    assert 1 / two_spheres(0.10, 2, 1.0).K_S[0, 0] == pytest.approx(2 * R0, rel=1e-12)


def test_sphere_pair_near_an_insulating_plane_equals_mirrored_pair():
    # an insulating plane is a mirror: the pair at 2 cm from the wall of a 1 m tank behaves like
    # the pair and its mirror image (same potentials) in unbounded water (far walls add < 0.1 %)
    from electrosense.meshes.tank import Tank
    from electrosense.meshes.tank_mesh import mesh_tank

    tank = Tank((1.0, 1.0, 1.0))
    gap = 0.02 + 0.01
    z = tank.floor_z_m + gap
    pair = concatenate([sphere_mesh(0.01, (-0.02, 0, z), 1, 2), sphere_mesh(0.01, (0.02, 0, z), 2, 2)])
    focus = np.array([[-0.02, 0, tank.floor_z_m], [0.02, 0, tank.floor_z_m], [0, 0, z]])
    in_tank = solve(WaterBoundary.from_meshes(pair, mesh_tank(tank, 0.006, focus, grading=0.8)), 1.0).K_S
    mirror = LabelledMesh(pair.vertices_m * [1, 1, -1] + [0, 0, 2 * tank.floor_z_m], pair.faces[:, ::-1],
                          pair.electrode, None, ("sensor",))
    mirrored = solve(WaterBoundary.from_meshes(concatenate([pair, mirror]), check=False), 1.0).K_S
    free = solve(WaterBoundary.from_meshes(pair), 1.0).K_S
    # K of the mirrored problem counts both halves
    assert in_tank[0, 0] == pytest.approx(mirrored[0, 0] / 2, rel=5e-3)
    assert abs(in_tank[0, 0] / free[0, 0] - 1) > 5 * abs(in_tank[0, 0] / (mirrored[0, 0] / 2) - 1)


def test_closed_tank_conserves_current():
    from electrosense.meshes.tank import Tank
    from electrosense.meshes.tank_mesh import mesh_tank

    pair = concatenate([sphere_mesh(0.01, (-0.03, 0, 0), 1, 1), sphere_mesh(0.01, (0.03, 0, 0), 2, 1)])
    sol = solve(WaterBoundary.from_meshes(pair, mesh_tank(Tank((0.3, 0.3, 0.3)), 0.05)), 1.0)
    C = sol.currents_A
    assert np.abs(C.sum(axis=0)).max() < 2e-3 * np.abs(C).max()   # no path to infinity


def test_floating_conductor_carries_no_net_current_and_raises_conductance():
    pair = concatenate([sphere_mesh(0.01, (-0.04, 0, 0), 1, 2), sphere_mesh(0.01, (0.04, 0, 0), 2, 2)])
    ball = sphere_mesh(0.015, (0, 0, 0), 0, 2, region="object_1")
    plain = solve(WaterBoundary.from_meshes(pair), 1.0)
    metal = solve(WaterBoundary.from_meshes(pair, None, (ball,), (True,)), 1.0)
    plastic = solve(WaterBoundary.from_meshes(pair, None, (ball,), (False,)), 1.0)
    assert metal.K_S[0, 0] > plain.K_S[0, 0] > plastic.K_S[0, 0]
    u, q = metal.surface([1.0, -1.0])
    wb = metal.boundary
    on = wb.conductor == 0
    areas = 0.5 * np.linalg.norm(np.cross(wb.triangles_m[:, 1] - wb.triangles_m[:, 0],
                                          wb.triangles_m[:, 2] - wb.triangles_m[:, 0]), axis=1)
    assert abs(np.sum(areas[on] * q[on])) < 1e-10 * np.sum(areas[on] * np.abs(q[on]))
    assert abs(u[on][0]) < 1e-9   # by symmetry the floating ball sits at 0 V


def test_isolate_matches_floating_potentials():
    sol = two_spheres(0.03, 2)
    V = sol.isolated_potentials([1.0, 0.0])
    assert sol.currents_A.sum(axis=0) @ V == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(isolate(sol.currents_A) @ [1.0, 0.0], sol.currents_A @ V, atol=1e-12)


def test_an_insulating_ball_between_two_plates_raises_the_resistance_as_maxwell_says():
    """A column of water between two plate electrodes (a cylinder's floor and free surface): the current
    density is uniform, sigma V / H (the field of a scene without a sensor); an insulating ball of volume
    fraction phi on the axis raises the resistance by Maxwell's 3 phi / 2 (a dilute suspension; the wall's and
    plates' images add O(phi): 0.06 % of it here at the finer mesh). The amplitude of every ball signal the
    real-tank studies compare rests on this."""
    from dataclasses import replace

    from electrosense.bem.solve import solve_scene
    from electrosense.meshes import Scene
    from electrosense.meshes.cylinder_tank import CylinderTank
    from electrosense.meshes.objects import Sphere
    from electrosense.meshes.surface_electrodes import PlateElectrode

    R, H, a, sigma = 0.1, 0.2, 0.02, 2.0
    scene = Scene(None, tank=CylinderTank(R, H), electrodes=[PlateElectrode("floor"), PlateElectrode("free_surface")])
    options = {"tank_edge_length_m": 0.02, "tank_focus_m": np.zeros((1, 3))}
    empty = solve_scene(scene, sigma, **options)
    ball = solve_scene(replace(scene, objects=(Sphere((0.0, 0.0, 0.0), radius_m=a),)), sigma, **options)
    R_empty, R_ball = 1 / empty.conductance.K_S[0, 0], 1 / ball.conductance.K_S[0, 0]
    assert R_empty == pytest.approx(H / (sigma * np.pi * R**2), rel=5e-3)
    J = empty.current_density_at([[0.0, 0.0, 0.0], [0.05, 0.0, 0.04]], np.array([0.5, -0.5]))
    assert J == pytest.approx(np.array([[0.0, 0.0, sigma / H]] * 2), abs=2e-3 * sigma / H)
    phi = (4 / 3 * np.pi * a**3) / (np.pi * R**2 * H)
    assert R_ball / R_empty - 1 == pytest.approx(1.5 * phi, rel=0.01)
