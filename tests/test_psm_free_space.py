"""PSM in unbounded water: closed forms and the conventions shared with the BEM."""
import numpy as np
import pytest

from electrosense.bem.conductance import ConductanceMatrix
from electrosense.psm import ModelError, PolySphericalModel, conductance, isolated_conductance, potential_coefficients

SIGMA = 0.0354


def test_two_spheres_closed_form():
    a1, a2, L = 0.007, 0.009, 0.2
    m = PolySphericalModel.collinear([a1, a2], [L])
    C = conductance(m, np.zeros((1, 4)), SIGMA, tank=None)
    expected = 4 * np.pi * SIGMA / (1 / a1 + 1 / a2 - 2 / L)
    assert isinstance(C, ConductanceMatrix)
    assert C.K_S[0, 0, 0] == pytest.approx(expected, rel=1e-13)
    assert C.S_S[0, 0, 0] == pytest.approx(expected, rel=1e-13)
    assert C.receiver_currents_A(1.0)[0, 0] == pytest.approx(expected, rel=1e-13)


def test_two_equal_spheres_far_apart_match_the_exact_bispherical_result():
    # Smythe's exact series for a = 1 cm, d = 10 cm, sigma = 1 S/m gives R = 14.32233 ohm (bem-notes);
    # the PSM neglects the mutual polarisation, O((a/d)^4)
    m = PolySphericalModel.collinear([0.01, 0.01], [0.1])
    C = conductance(m, np.zeros((1, 4)), 1.0)
    assert C.resistance_ohm[0, 0] == pytest.approx(14.32233, rel=2e-4)


def test_K_is_symmetric_with_zero_row_sums_and_independent_of_the_emitter():
    radii, gaps = [0.0072, 0.0074, 0.0074, 0.0072], [0.0785, 0.0769, 0.0785]
    K4 = conductance(PolySphericalModel.collinear(radii, gaps, emitter=4), np.zeros((1, 4)), SIGMA).K_S[0]
    K2 = conductance(PolySphericalModel.collinear(radii, gaps, emitter=2), np.zeros((1, 4)), SIGMA).K_S[0]
    np.testing.assert_allclose(K4, K4.T, atol=1e-15)
    np.testing.assert_allclose(K4.sum(axis=1), 0, atol=1e-15)
    np.testing.assert_allclose(K4, K2, rtol=1e-12)
    assert np.all(np.linalg.eigvalsh(K4)[1:] > 0)


def test_S_is_4_pi_sigma_inverse_of_P_R_P():
    m = PolySphericalModel.collinear([0.0072, 0.0074, 0.0074, 0.0072], [0.0785, 0.0769, 0.0785])
    R = potential_coefficients(m.radii_m, m.centres_m)
    P = np.vstack([np.eye(3), -np.ones((1, 3))])
    S_paper = 4 * np.pi * SIGMA * np.linalg.inv(P.T @ R @ P)
    S = conductance(m, np.zeros((1, 4)), SIGMA).S_S[0]
    np.testing.assert_allclose(S, S_paper, rtol=1e-12)
    np.testing.assert_allclose(isolated_conductance(R / (4 * np.pi * SIGMA), 4)[:3, :3], S_paper, rtol=1e-12)


def test_unbounded_water_does_not_depend_on_the_pose():
    m = PolySphericalModel.collinear([0.0072, 0.0074, 0.0074, 0.0072], [0.0785, 0.0769, 0.0785])
    poses = np.array([[0, 0, 0, 0], [3.0, -2.0, 1.0, 0.7], [-1.0, 5.0, 0.0, 2.5]])
    K = conductance(m, poses, SIGMA).K_S
    np.testing.assert_allclose(K, np.broadcast_to(K[0], K.shape), rtol=1e-12)


@pytest.mark.parametrize("radii, gaps, what", [
    ([0.01, 0.01], [0.015], "overlap"),
    ([0.01, -0.01], [0.1], "positive"),
])
def test_impossible_models_are_refused(radii, gaps, what):
    with pytest.raises(ModelError, match=what):
        PolySphericalModel.collinear(radii, gaps)


def test_model_json_round_trip(tmp_path):
    m = PolySphericalModel.collinear([0.0072, 0.0074, 0.0074, 0.0072], [0.0785, 0.0769, 0.0785],
                                     gamma_criterion=1e-4, reference={"S_S": [[1.0]]},
                                     electrode_areas_m2=[1e-4, 2e-4, 2e-4, 1e-4])
    path = tmp_path / "electrosense.psm.json"
    m.save(path)
    back = PolySphericalModel.load(path)
    np.testing.assert_array_equal(back.radii_m, m.radii_m)
    np.testing.assert_array_equal(back.centres_m, m.centres_m)
    np.testing.assert_array_equal(back.electrode_areas_m2, m.electrode_areas_m2)
    assert (back.emitter, back.gamma_criterion, back.reference) == (4, 1e-4, {"S_S": [[1.0]]})
    assert back.centres_m[0, 0] > 0  # electrode 1 at the head, +x
    assert back == m and back != PolySphericalModel.collinear([0.0072] * 4, [0.0785, 0.0769, 0.0785])


def test_an_empty_trajectory_gives_an_empty_batch():
    m = PolySphericalModel.collinear([0.007, 0.007], [0.2])
    from electrosense.meshes.tank import Tank

    C = conductance(m, np.zeros((0, 4)), SIGMA, Tank((1.0, 1.0, 1.0)))
    assert C.K_S.shape == (0, 2, 2)


def test_sphere_centres_follow_the_pose_convention_of_meshes():
    from electrosense.meshes.pose import sensor_to_tank
    from electrosense.psm.conductance import sphere_centres_m

    m = PolySphericalModel(np.array([0.005, 0.006, 0.005]), np.array([[0.1, 0.01, 0.0], [0.0, 0.0, 0.02], [-0.1, 0.0, 0.0]]))
    poses = np.array([[0.1, -0.2, 0.05, 0.0], [0.0, 0.3, -0.1, 1.2], [0.2, 0.1, 0.0, np.pi / 2]])
    np.testing.assert_allclose(sphere_centres_m(m, poses), sensor_to_tank(m.centres_m, poses), atol=1e-15)
    head = sphere_centres_m(m, poses[2:])[0, 0]
    assert head[1] > poses[2, 1]  # yaw pi/2: the head points to +y
