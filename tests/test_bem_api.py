"""The public API: conductance_matrix, surface solutions and fields, PoseSweep, the command."""
import json
import pickle

import numpy as np
import pytest

from electrosense.bem import ConductanceMatrix, PoseSweep, conductance_matrix, solve_scene
from electrosense.meshes import Pose, Scene, Tank, preset

H = 0.008  # coarse sensor meshes keep these tests fast


@pytest.fixture(scope="module")
def free_solution():
    return solve_scene(Scene(preset("angels-2")), 1.0, edge_length_m=H)


def test_conductance_matrix_invariants(free_solution):
    g = free_solution.conductance
    assert isinstance(g, ConductanceMatrix) and g.K_S.shape == (2, 2)
    assert g.info["triangles"] > 0 and g.info["seconds"] > 0
    assert g.asymmetry < 1e-3 and g.row_sum_residue < 1e-12
    assert g.S_S[0, 0] > 0
    assert g.K_S[0, 0] == pytest.approx(g.K_S[1, 1], rel=2e-3)   # head and tail are mirror images


def test_conductance_is_proportional_to_sigma(free_solution):
    g = conductance_matrix(Scene(preset("angels-2")), 0.0354, edge_length_m=H)
    np.testing.assert_allclose(g.K_S, free_solution.K_S * 0.0354, rtol=1e-10)


def test_potential_field(free_solution):
    # emitter (2) at 1 V, receiver at 0 V, isolated: by symmetry the sensor floats to +-0.5 V
    V = free_solution.isolated_potentials([0.0, 1.0])
    np.testing.assert_allclose(V, [-0.5, 0.5], atol=2e-3)
    u = free_solution.potential_at([[0.0, 0.05, 0.0], [0.0, 0.0, 0.3], [50.0, 0.0, 0.0]])
    assert np.abs(u).max() < 2e-3                       # mid-plane and far away
    # continuous up to the emitter's surface: 50 um beyond the tail tip, minus the ohmic drop J d / sigma
    I = free_solution.electrode_currents_A([0.0, 1.0])[1]
    drop = I / (2 * np.pi * 0.01**2) * 5e-5
    near_tail = free_solution.potential_at([[-0.10005, 0.0, 0.0]])
    assert 0.5 - 5 * drop < near_tail[0] < 0.5   # the tip collects a few times the mean current density
    # the field points from the emitter (tail, -x) to the receiver (head, +x) on the mid-plane
    J = free_solution.current_density_at([[0.0, 0.03, 0.0]])
    assert J[0, 0] > 0 and abs(J[0, 1]) < 1e-3 * abs(J[0, 0])


def test_surface_solution_as_vtk(free_solution):
    poly = free_solution.to_pyvista()
    n = free_solution.boundary.n_triangles
    for name in ("potential_V", "current_density_A_per_m2", "electrode"):
        assert poly.cell_data[name].shape == (n,)
    on = poly.cell_data["electrode"] > 0
    assert np.all(poly.cell_data["current_density_A_per_m2"][~on] == 0)
    # the current density integrated over the emitter equals its current
    areas = poly.compute_cell_sizes().cell_data["Area"]
    J = poly.cell_data["current_density_A_per_m2"]
    I_emitter = np.sum((areas * J)[poly.cell_data["electrode"] == 2])
    V = free_solution.isolated_potentials([0.0, 1.0])
    assert I_emitter == pytest.approx((free_solution.K_surface_S @ V)[1], rel=1e-9)
    # the conductance matrix carries the edge correction on top (bem.edge_correction): a few tenths of a percent
    assert I_emitter == pytest.approx(free_solution.electrode_currents_A([0.0, 1.0])[1], rel=1e-2)


@pytest.fixture(scope="module")
def tank_sweep():
    return PoseSweep(preset("angels-2"), Tank((0.4, 0.3, 0.3)), sigma_S_per_m=1.0, edge_length_m=H,
                     tank_edge_length_m=0.03)


def test_pose_sweep_matches_the_direct_solver(tank_sweep):
    poses = np.array([[0.0, 0.0, 0.0, 0.0], [0.07, 0.03, -0.02, 0.4]])
    g = tank_sweep.conductance(poses)
    assert g.K_S.shape == (2, 2, 2)
    for p, K in zip(poses, g.K_S):
        direct = conductance_matrix(Scene(preset("angels-2"), Pose.from_array(p), Tank((0.4, 0.3, 0.3))), 1.0,
                                    edge_length_m=H, tank_edge_length_m=0.03, tank_focus_m=tank_sweep.focus_m)
        # the sweep integrates the tank block's double layer exactly, the direct solver by its centroid rule
        # beyond FAR diameters (bem.operators): a row-sum residue of ~1e-4 in the direct solution
        np.testing.assert_allclose(K, direct.K_S, rtol=1e-4)
    assert g.row_sum_residue < 5e-3


def test_pose_sweep_pickles(tank_sweep):
    poses = np.array([[0.05, 0.0, 0.0, 0.0]])
    clone = pickle.loads(pickle.dumps(tank_sweep))
    np.testing.assert_allclose(clone.conductance(poses).K_S, tank_sweep.conductance(poses).K_S, rtol=1e-12)


def test_unbounded_sweep_is_pose_independent():
    sweep = PoseSweep(preset("angels-2"), None, sigma_S_per_m=1.0, edge_length_m=H)
    g = sweep.conductance(np.array([[0, 0, 0, 0], [1.0, -2.0, 0.3, 2.0]]))
    single = solve_scene(Scene(preset("angels-2")), 1.0, edge_length_m=H)   # the same method as the sweep
    np.testing.assert_allclose(g.K_S[0], single.K_S, rtol=1e-9)
    np.testing.assert_allclose(g.K_S[1], single.K_S, rtol=1e-9)
    full = solve_scene(Scene(preset("angels-2")), 1.0, edge_length_m=H, axisymmetric=False)
    np.testing.assert_allclose(g.K_S[0], full.K_S, rtol=2e-4)   # the reduction against the full collocation


def test_lone_sensor_is_independent_of_its_pose_in_unbounded_water():
    # the axisymmetric reduction finds its rings in the sensor frame, whatever the pose
    poses = [Pose(0.0, 0.0, 0.0, 0.0), Pose(0.05, 0.02, -0.01, 1.0)]
    solutions = [solve_scene(Scene(preset("angels-2"), p), 1.0, edge_length_m=H) for p in poses]
    assert all(s.info.get("method") == "axisymmetric reduction" for s in solutions)
    np.testing.assert_allclose(solutions[1].K_S, solutions[0].K_S, rtol=1e-12)
    # the field moves with the sensor: a point fixed in the sensor frame sees the same potential
    local = np.array([0.05, 0.03, 0.01])
    u = [s.potential_at(p.to_tank(local[None]))[0] for s, p in zip(solutions, poses)]
    assert abs(u[0]) > 1e-3 and u[1] == pytest.approx(u[0], rel=1e-9)


def test_conductance_command(tmp_path, free_solution):
    from click.testing import CliRunner

    from electrosense.validation.cli import main

    out = tmp_path / "g.json"
    result = CliRunner().invoke(main, ["conductance", "--sensor", "angels-2", "--unbounded", "--sigma", "1", "--edge-length", str(H),
                                       "--json", str(out)])
    assert result.exit_code == 0, result.output
    assert "R1 =" in result.output
    d = json.loads(out.read_text())
    for key in ("sigma_S_per_m", "emitter", "K_S", "S_S", "triangles", "seconds"):
        assert key in d
    np.testing.assert_allclose(d["K_S"], free_solution.K_S, rtol=1e-10)
    assert ConductanceMatrix.from_json_dict(d).emitter == 2
    assert d["edge_correction"] is True
    np.testing.assert_allclose(d["K_surface_S"], free_solution.K_surface_S, rtol=1e-10)
    raw = tmp_path / "raw.json"
    result = CliRunner().invoke(main, ["conductance", "--sensor", "angels-2", "--unbounded", "--sigma", "1", "--edge-length", str(H),
                                       "--no-edge-correction", "--json", str(raw)])
    assert result.exit_code == 0, result.output
    assert "no edge correction" in result.output
    d_raw = json.loads(raw.read_text())
    assert d_raw["edge_correction"] is False
    np.testing.assert_allclose(d_raw["K_S"], free_solution.K_surface_S, rtol=1e-10)
    assert d_raw["S_S"][0][0] < d["S_S"][0][0]        # the surface mesh alone is low at the electrode edges


def test_conductance_command_refuses_a_sensor_out_of_the_tank():
    from click.testing import CliRunner

    from electrosense.validation.cli import main

    result = CliRunner().invoke(main, ["conductance", "--sensor", "angels-2", "--tank", "0.3,0.3,0.3",
                                       "--pose", "0.1,0,0,0"])
    assert result.exit_code != 0 and "sensor" in result.output


def test_pose_sweep_with_a_conducting_object_and_contact_impedance():
    from electrosense.meshes import Sphere

    tank = Tank((0.4, 0.3, 0.3))
    ball = (Sphere(centre_m=(0.0, 0.08, 0.0), radius_m=0.02, conductivity_S_per_m=float("inf")),)
    sweep = PoseSweep(preset("angels-2"), tank, ball, sigma_S_per_m=1.0, contact_impedance_ohm_m2=1e-3,
                      edge_length_m=H, tank_edge_length_m=0.04)
    pose = np.array([[0.03, 0.0, 0.0, 0.2]])
    K = sweep.conductance(pose).K_S[0]
    direct = conductance_matrix(Scene(preset("angels-2"), Pose.from_array(pose[0]), tank, ball), 1.0, 1e-3,
                                edge_length_m=H, tank_edge_length_m=0.04, tank_focus_m=sweep.focus_m)
    # the same meshes; the direct solver's centroid rule beyond FAR diameters (above) leaves ~1e-5
    np.testing.assert_allclose(K, direct.K_S, rtol=3e-5)


def test_another_contact_impedance_shares_the_tank_and_equals_a_sweep_built_with_it():
    from electrosense.meshes import Sphere

    tank = Tank((0.4, 0.3, 0.3))
    ball = (Sphere(centre_m=(0.0, 0.08, 0.0), radius_m=0.02, conductivity_S_per_m=float("inf")),)
    poses = np.array([[0.03, 0.0, 0.0, 0.2], [-0.1, 0.05, 0.0, 1.0]])
    sweep = PoseSweep(preset("angels-2"), tank, ball, sigma_S_per_m=1.0, edge_length_m=H, tank_edge_length_m=0.04)
    K0 = sweep.conductance(poses).K_S
    z = [1e-3, 4e-4]
    other = sweep.with_contact_impedance(z)
    assert other._A_e is sweep._A_e                                   # the tank's blocks are not made again
    built = PoseSweep(preset("angels-2"), tank, ball, sigma_S_per_m=1.0, contact_impedance_ohm_m2=z, edge_length_m=H,
                      tank_mesh=sweep.tank_mesh)
    # equal up to the float32 factors and the range finder's first sample (about 1e-8)
    np.testing.assert_allclose(other.conductance(poses).K_S, built.conductance(poses).K_S, rtol=1e-6)
    assert sweep.contact_impedance_ohm_m2 is None and other._lu is not sweep._lu   # the original is unchanged
    np.testing.assert_allclose(sweep.conductance(poses).K_S, K0, rtol=1e-6)
    assert np.all(np.abs(other.conductance(poses).K_S[:, 0, 0]) < np.abs(K0[:, 0, 0]))
    # a sweep whose tank mesh is known before any pose (its focus given) makes the tank once, for every copy
    fresh = PoseSweep(preset("angels-2"), tank, ball, sigma_S_per_m=1.0, edge_length_m=H, tank_mesh=sweep.tank_mesh)
    assert fresh.with_contact_impedance(z)._A_e is fresh._A_e


@pytest.mark.parametrize("scene", ["closed tank", "tank and a conducting ball", "objects in unbounded water"])
def test_woodbury_poses_equal_the_factorised_schur_complement(scene, monkeypatch):
    """Each pose solved by the Woodbury formula on the once-factorised, regularised environment block gives the
    K of a fresh factorisation of the Schur complement, in a closed tank (whose block alone is singular),
    with a conductor (its extra unknowns), and without a tank."""
    import electrosense.bem.sweep as sweep_module
    from electrosense.meshes import Sphere

    tank = None if scene == "objects in unbounded water" else Tank((0.4, 0.3, 0.3))
    objects = () if scene == "closed tank" else (
        Sphere(centre_m=(0.0, 0.08, 0.0), radius_m=0.02, conductivity_S_per_m=float("inf")),)
    poses = np.array([[0.03, 0.0, 0.0, 0.2], [-0.1, -0.02, 0.03, -0.5]])

    def K(min_rcond):
        monkeypatch.setattr(sweep_module, "WOODBURY_MIN_RCOND", min_rcond)
        sweep = PoseSweep(preset("angels-2"), tank, objects, sigma_S_per_m=1.0, edge_length_m=H,
                          tank_edge_length_m=0.05)
        return sweep.conductance(poses).K_S, sweep.timings["woodbury"]

    (K_woodbury, used), (K_schur, not_used) = K(0.0), K(np.inf)
    assert used and not not_used
    np.testing.assert_allclose(K_woodbury, K_schur, rtol=1e-10, atol=1e-12 * np.abs(K_schur).max())


def test_float32_woodbury_factors_refined_give_the_float64_poses(monkeypatch):
    """The regularised tank block factorised in float32 and each pose refined on float64 residuals gives the K
    of float64 factors; a sweep whose factors go to the disk cache keeps them float64."""
    import electrosense.bem.sweep as sweep_module

    tank, poses = Tank((0.4, 0.3, 0.3)), np.array([[0.03, 0.0, 0.0, 0.2], [-0.1, -0.02, 0.03, -0.5]])

    def sweep(**options):
        s = PoseSweep(preset("angels-2"), tank, (), sigma_S_per_m=1.0, edge_length_m=H, tank_edge_length_m=0.05,
                      **options)
        return s, s.conductance(poses).K_S

    low, K_low = sweep()
    assert low._woodbury[0].dtype == np.float32
    monkeypatch.setattr(sweep_module, "LOW_PRECISION_MIN_RCOND", np.inf)
    double, K_double = sweep()
    assert double._woodbury[0].dtype == np.float64
    np.testing.assert_allclose(K_low, K_double, rtol=1e-10, atol=1e-12 * np.abs(K_double).max())
    monkeypatch.setattr(sweep_module, "LOW_PRECISION_MIN_RCOND", 0.0)
    cached, _ = sweep(cache_environment=True)
    assert cached._woodbury[0].dtype == np.float64


def test_axisymmetric_reduction_matches_the_full_collocation(free_solution):
    from electrosense.bem.axisymmetric import solve_axisymmetric

    assert free_solution.info.get("method") == "axisymmetric reduction"   # the default for a lone sensor
    full = solve_scene(Scene(preset("angels-2")), 1.0, edge_length_m=H, axisymmetric=False)
    assert "method" not in full.info
    np.testing.assert_allclose(free_solution.K_S, full.K_S, rtol=1e-4)
    quick = solve_axisymmetric(full.boundary, 1.0, targets_per_class=4)
    np.testing.assert_allclose(quick.K_S, full.K_surface_S, rtol=1e-3)   # both without the edge correction
    # surface potentials agree in the mean (single faces of the zipped transition bands, where the
    # mesh departs most from rotational symmetry, differ by up to ~1 % of the potential step)
    u_full, _ = full.surface([0.0, 1.0])
    u_axi, _ = free_solution.surface([0.0, 1.0])
    a = full.boundary.mesh.areas_m2
    assert np.sqrt(np.sum(a * (u_axi - u_full) ** 2) / a.sum()) < 1e-3


def test_pose_sweep_reuses_the_sensor_block_from_the_disk_cache(tmp_path):
    poses = np.array([[0.02, 0.01, 0.0, 0.3]])
    first = PoseSweep(preset("angels-2"), Tank((0.4, 0.3, 0.3)), sigma_S_per_m=1.0, edge_length_m=H,
                      tank_edge_length_m=0.04, block_cache=tmp_path, cache_environment=True)
    assert first.timings["sensor_block_cached"] is False
    assert len(list(tmp_path.iterdir())) == 1   # one entry, no temporary folder left behind
    second = PoseSweep(preset("angels-2"), Tank((0.4, 0.3, 0.3)), sigma_S_per_m=1.0, edge_length_m=H,
                       tank_edge_length_m=0.04, block_cache=tmp_path, cache_environment=True)
    assert second.timings["sensor_block_cached"] is True
    K_first = first.conductance(poses).K_S       # the tank's block made, factorised and stored
    assert first.timings["environment_block_cached"] is False
    K_second = second.conductance(poses).K_S     # ... and read back
    assert second.timings["environment_block_cached"] is True
    np.testing.assert_allclose(K_second, K_first, rtol=1e-12)
    # another conductivity changes the block (through the flux scaling): a new entry, not a stale one
    other = PoseSweep(preset("angels-2"), Tank((0.4, 0.3, 0.3)), sigma_S_per_m=2.0, edge_length_m=H,
                      tank_edge_length_m=0.04, block_cache=tmp_path, contact_impedance_ohm_m2=1e-3)
    assert other.timings["sensor_block_cached"] is False
