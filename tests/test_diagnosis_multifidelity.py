"""The BEM-corrected PSM baseline (validation.diagnosis.multifidelity) and the parsimony rule of the selection."""
import numpy as np
import pytest

from electrosense.validation.diagnosis.blind import BlindSetup
from electrosense.validation.diagnosis.forward import PointElectrodeSimulator, receiver_currents
from electrosense.validation.diagnosis.multifidelity import bem_correction, choose_bem_poses
from electrosense.validation.diagnosis.observations import Observations
from electrosense.validation.diagnosis.select import nested_angle_deg


def _obs(n=30):
    setup = BlindSetup()
    x = np.linspace(-0.35, 0.35, n)
    poses = np.column_stack([x, np.zeros((n, 3))])
    passes = np.repeat([0, 1], [n // 2, n - n // 2])
    obs = Observations(poses, np.ones((n, 3)), setup.sensor, setup.tank, 0.0354, t_s=np.arange(n) * 0.1,
                       passes=passes)
    K = PointElectrodeSimulator(setup.sensor, 0.0354)(poses, setup.tank, ())
    return obs, K


def test_chosen_poses_hold_the_ends_of_each_pass_and_crowd_where_the_tank_matters():
    D = np.concatenate([np.zeros(50), np.linspace(0, 1, 10) ** 2])  # the wall at the end of the pass
    idx = choose_bem_poses(D, [np.arange(60)], 12)
    assert idx[0] == 0 and idx[-1] == 59
    assert np.sum(idx >= 50) > np.sum(idx < 50) * 10 / 50  # denser per sample near the wall than far from it
    two = choose_bem_poses(np.zeros(20), [np.arange(10), np.arange(10, 20)], 6)
    assert {0, 9, 10, 19} <= set(two.tolist())


def test_a_correction_linear_along_the_path_is_recovered_exactly_between_the_bem_poses():
    obs, K_psm = _obs()
    # "BEM" = PSM times a factor whose log is linear in the sample index within each pass
    s = np.zeros(obs.n_poses)
    for idx in obs.pass_indices():
        s[idx] = np.linspace(0.0, 0.05, len(idx))
    factor = np.exp(s)[:, None, None] * np.array([[1, 1.02, 0.99, 1.01], [1.02, 1, 1.0, 0.98],
                                                    [0.99, 1.0, 1, 1.03], [1.01, 0.98, 1.03, 1]])[None]
    off = K_psm * factor * (1 - np.eye(4))
    K_true = off - np.eye(4) * off.sum(-1, keepdims=True)
    idx = np.array([0, 7, 14, 15, 22, 29])
    c = bem_correction(obs, K_psm, K_true[idx], idx)
    K = c.corrected(K_psm)
    np.testing.assert_allclose(K, K_true, rtol=1e-10, atol=1e-18)
    np.testing.assert_allclose(K.sum(-1), 0.0, atol=1e-15)
    interior = [1, 4]  # samples 7 and 22: inside their pass, predicted exactly by their neighbours
    assert np.max(np.abs(c.leave_one_out[interior])) < 1e-10
    ends = [0, 2, 3, 5]  # a pass's end left out is held at its neighbour's value: the linear trend shows
    assert np.all(np.abs(c.leave_one_out[ends]) > 1e-3)
    I = receiver_currents(K_psm[idx], obs.emitter) / receiver_currents(K_true[idx], obs.emitter) - 1
    np.testing.assert_allclose(c.psm_vs_bem, I)
    assert np.all(c.error[idx] == 0)


def test_a_correction_that_bends_has_a_nonzero_error_estimate_between_the_bem_poses():
    obs, K_psm = _obs()
    s = np.zeros(obs.n_poses)
    for idx in obs.pass_indices():
        s[idx] = 0.05 * np.linspace(0.0, 1.0, len(idx)) ** 4
    off = K_psm * np.exp(s)[:, None, None] * (1 - np.eye(4))
    K_true = off - np.eye(4) * off.sum(-1, keepdims=True)
    idx = np.array([0, 5, 10, 14, 15, 20, 25, 29])
    c = bem_correction(obs, K_psm, K_true[idx], idx)
    I_true = receiver_currents(K_true, obs.emitter)
    actual = np.abs(receiver_currents(c.corrected(K_psm), obs.emitter) / I_true - 1)
    between = np.setdiff1d(np.arange(obs.n_poses), idx)
    assert actual[between].max() > 0
    assert np.all(c.error[between].max(axis=1) >= 0.5 * actual[between].max(axis=1) - 1e-12)


def test_a_sign_disagreement_is_refused():
    obs, K_psm = _obs()
    with pytest.raises(ValueError, match="sign"):
        bem_correction(obs, K_psm, -K_psm[[0, 29]], np.array([0, 29]))


def test_nested_angle_is_zero_for_a_column_inside_a_span_and_not_otherwise():
    rng = np.random.default_rng(1)
    J = rng.normal(size=(50, 3))
    assert nested_angle_deg(J @ np.array([[1.0], [1.0], [1.0]]), J) < 1e-6
    assert nested_angle_deg(rng.normal(size=(50, 1)), J) > 10
    assert nested_angle_deg(J, J[:, :1]) == 90.0  # a larger span is never nested in a smaller one
