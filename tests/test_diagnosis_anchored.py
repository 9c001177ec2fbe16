"""The BEM-anchored baseline's pieces, the model-error rules of the selection, readable numbers."""
from types import SimpleNamespace

import numpy as np
import pytest

from electrosense.meshes.tank import Tank
from electrosense.validation.diagnosis.anchored import AnchorStore, RBFInterpolant, pose_features, psm_usable
from electrosense.validation.diagnosis.report import readable_estimate, readable_shrink
from electrosense.validation.diagnosis.select import SelectionRules, _fewest_reaching_floor, forward_selection
from electrosense.validation.diagnosis.unseen import random_passes, random_sensor, random_setup


def test_closed_form_leave_one_out_equals_refitting():
    rng = np.random.default_rng(3)
    X = rng.uniform(-1, 1, (14, 3))
    y = np.column_stack([np.sin(2 * X[:, 0]) + X[:, 1] ** 2, np.cos(X[:, 2])])
    loo = RBFInterpolant(X, y).leave_one_out
    for i in range(len(X)):
        keep = np.delete(np.arange(len(X)), i)
        direct = y[i] - RBFInterpolant(X[keep], y[keep])(X[i:i + 1])[0]
        assert loo[i] == pytest.approx(direct, rel=1e-6, abs=1e-9)


def test_a_node_and_its_mirror_images_are_left_out_together():
    """A tank map's node lends the interpolant its mirror image across a symmetry plane, with its value: left
    out alone, the node was predicted from its own image, and the closed form said it was known. With ``groups``
    the block form equals refitting without the node and its image, and is larger beside the plane."""
    rng = np.random.default_rng(1)
    X = rng.uniform(-1, 1, (30, 2))
    X[:, 1] = np.abs(X[:, 1])                       # the fundamental domain y >= 0 of a function even in y
    near = np.flatnonzero(X[:, 1] < 0.3)
    XA = np.vstack([X, X[near] * [1.0, -1.0]])      # the images across y = 0
    y = np.sin(2 * XA[:, :1]) * np.cos(XA[:, 1:])
    groups = np.r_[np.arange(len(X)), near]
    grouped = RBFInterpolant(XA, y, degree=2, groups=groups).leave_one_out
    for i in range(len(X)):
        keep = groups != i
        rows = np.flatnonzero(~keep)                  # the node, and its image where it has one
        direct = y[rows] - RBFInterpolant(XA[keep], y[keep], degree=2)(XA[rows])
        np.testing.assert_allclose(grouped[rows], direct, rtol=1e-6, atol=1e-9)
    alone = RBFInterpolant(XA, y, degree=2).leave_one_out
    assert np.sqrt(np.mean(grouped[near] ** 2)) > 2 * np.sqrt(np.mean(alone[near] ** 2))
    with pytest.raises(ValueError, match="one label per node"):
        RBFInterpolant(XA, y, groups=groups[:-1])


def test_regressors_enter_the_fit_the_leave_one_out_errors_and_the_gradient():
    """A field that is a cheaper model's values scaled, plus a smooth remainder: its leave-one-out errors in closed
    form are those of refitting, and its gradient carries the regressors' own."""
    rng = np.random.default_rng(7)
    X = rng.uniform(-1, 1, (24, 2))

    def cheap(Z):
        return np.c_[np.exp(Z[:, 0]), np.sin(3 * Z[:, 1])]

    def cheap_gradient(Z):
        g = np.zeros((len(Z), 2, 2))
        g[:, 0, 0], g[:, 1, 1] = np.exp(Z[:, 0]), 3 * np.cos(3 * Z[:, 1])
        return g

    y = np.c_[cheap(X) @ [0.3, -0.2] + 0.05 * X[:, 0] * X[:, 1], cheap(X)[:, 1]]
    f = RBFInterpolant(X, y, regressors=cheap(X))
    for i in (0, 5, 17):
        keep = np.delete(np.arange(len(X)), i)
        direct = y[i] - RBFInterpolant(X[keep], y[keep], regressors=cheap(X[keep]))(X[i:i + 1], cheap(X[i:i + 1]))[0]
        assert f.leave_one_out[i] == pytest.approx(direct, rel=1e-6, abs=1e-9)
    assert np.abs(f.leave_one_out[:, 1]).max() < 1e-8            # the regressor itself is predicted exactly
    assert np.abs(f.leave_one_out[:, 0]).max() < 0.3 * np.abs(RBFInterpolant(X, y).leave_one_out[:, 0]).max()
    Z = rng.uniform(-0.8, 0.8, (5, 2))
    v, g = f.value_and_gradient(Z, cheap(Z), cheap_gradient(Z))
    assert np.allclose(v, f(Z, cheap(Z)))
    for j in range(2):
        d = np.zeros(2)
        d[j] = 1e-6
        fd = (f(Z + d, cheap(Z + d)) - f(Z - d, cheap(Z - d))) / 2e-6
        assert np.allclose(fd, g[:, j], atol=1e-6)
    again = RBFInterpolant.from_coefficients(X, f.coef, n_regressors=2)
    assert np.allclose(again(Z, cheap(Z)), v, rtol=1e-12)
    with pytest.raises(ValueError, match="regressors"):
        f(Z)


def test_interpolant_reproduces_nodes_and_linear_fields():
    rng = np.random.default_rng(4)
    X = rng.uniform(0, 1, (20, 6))
    y = X @ rng.normal(size=(6, 2)) + 0.5
    f = RBFInterpolant(X, y)
    assert np.allclose(f(X), y, atol=1e-8)
    Z = rng.uniform(0, 1, (5, 6))
    assert np.allclose(f(Z), Z @ np.linalg.lstsq(np.c_[X], y - 0.5, rcond=None)[0] + 0.5, atol=1e-6)
    assert np.abs(f.leave_one_out).max() < 1e-6  # a linear field is predicted exactly from the others


def test_anchor_store_is_keyed_by_geometry_never_by_name(tmp_path):
    rng = np.random.default_rng(5)
    sensor = random_sensor(rng, 4, name="../../evil name")
    renamed = random_sensor(np.random.default_rng(5), 4, name="other")
    tank = Tank((0.8, 0.6, 0.5), 0.4)
    a, b = AnchorStore(sensor, tank, folder=tmp_path), AnchorStore(renamed, tank, folder=tmp_path)
    assert a.key == b.key and "evil" not in str(a.path) and a.path.parent == tmp_path
    assert AnchorStore(sensor, Tank((0.8, 0.6, 0.5), 0.35), folder=tmp_path).key != a.key
    assert a.load() is None
    a.save({"poses": np.zeros((2, 4)), "K_unit": np.ones((2, 4, 4)), "focus_m": np.zeros((3, 3))})
    assert b.load()["K_unit"].shape == (2, 4, 4)


def test_random_setups_are_valid_and_passes_fit_the_tank():
    for seed in range(6):
        setup = random_setup(np.random.default_rng(seed))
        assert 3 <= setup.sensor.n_electrodes <= 6
        poses, t, passes = random_passes(setup, np.random.default_rng(seed + 10), 3, 9)
        tips = pose_features(setup.sensor, poses).reshape(-1, 2, 3)
        assert np.all(setup.tank.distance_to_boundary_m(tips) > 0.01)
        assert np.all(np.diff(t) > 0) and set(passes.tolist()) == {0, 1, 2}


def test_psm_usable_flags_spheres_beyond_a_wall():
    model = SimpleNamespace(centres_m=np.array([[0.1, 0, 0], [-0.1, 0, 0]]), radii_m=np.array([0.01, 0.01]))
    tank = Tank((1.0, 1.0, 1.0))
    poses = np.array([[0.0, 0, 0, 0], [0.385, 0, 0, 0], [0.395, 0, 0, 0]])
    assert psm_usable(model, poses, tank).tolist() == [True, True, False]


def _cand(name, gap, score, k, other_forms=()):
    return SimpleNamespace(name=name, heldout_gap=gap, score=score, n_params=k, other_forms=list(other_forms),
                           at_bound=[])


def test_one_parameter_reaching_the_floor_beats_three():
    rules, floor = SelectionRules(), 0.001
    current = _cand("none", 0.02, 1e4, 0)
    three = _cand("channel_gain", 0.0010, 900.0, 3)
    one = _cand("conductivity", 0.0012, 950.0, 1)
    assert _fewest_reaching_floor(three, [three, one], current, rules, floor) is one
    far = _cand("conductivity", 0.0019, 1900.0, 1)  # beyond 1.5x the floor: not a full explanation
    assert _fewest_reaching_floor(three, [three, far], current, rules, floor) is three
    # a candidate's one-parameter form counts even where its richer form scored better (a common contact
    # impedance against per-electrode ones)
    common = _cand("contact_impedance", 0.0011, 940.0, 1)
    per_electrode = _cand("contact_impedance", 0.00099, 905.0, 4, other_forms=[common])
    assert _fewest_reaching_floor(three, [three, per_electrode], current, rules, floor) is common


def test_gap_within_the_model_error_is_none_and_says_where_the_model_is_the_limit():
    noise, floor = 0.001, 0.002  # the baseline's own error ~1.7e-3, largest near one wall
    by_place = {"centre": 0.0005, "wall_y+": 0.003}
    inside = forward_selection(None, [_cand("none", 0.0028, 50.0, 0)], [], noise, floor=floor,
                               model_error_by_place=by_place)
    assert inside.verdict == "none" and inside.chosen == []
    note = inside.steps[-1]["stop"]
    assert "within the model's own error" in note and "wall_y+" in note and "centre" not in note
    beyond = forward_selection(None, [_cand("none", 0.0035, 50.0, 0)], [], noise, floor=floor)
    assert beyond.verdict == "unexplained"
    at_noise = forward_selection(None, [_cand("none", 0.0014, 50.0, 0)], [], noise, floor=noise)
    assert at_noise.verdict == "none"


def test_numbers_a_person_can_read():
    assert readable_estimate(-0.025123, 0.00041) == "-0.0251 +- 0.0004"
    assert readable_estimate(7.867e-07, 3.7e2, "rad", span=0.4).startswith("not determined")
    assert "e+04" not in readable_shrink(0.001, 0.1047) and "worse" in readable_shrink(0.001, 0.1047)
    assert readable_shrink(0.02, 0.0016) == "92 % of the gap removed"


def test_repeated_passes_cost_one_bem_solve_per_distinct_pose(tmp_path, monkeypatch):
    """Passes that repeat a path log the same poses: the BEM runs once per distinct pose (a stand-in sweep counts
    them and answers the PSM's K, slightly changed, so that the bookkeeping is checked without the BEM's cost)."""
    from electrosense import bem
    from electrosense.validation.diagnosis.anchored import AnchorStore, anchored_baseline
    from electrosense.validation.diagnosis.blind import assemble
    from electrosense.validation.simulation.models import pose_evaluator

    rng = np.random.default_rng(11)
    setup = random_setup(rng, 4)
    path, t, passes = random_passes(setup, rng, 1, 12)
    poses = np.vstack([path, path[::-1], path])
    t = np.arange(len(poses)) * 5.0
    passes = np.repeat([0, 1, 2], len(path))
    solved = []

    class CountingSweep:
        def __init__(self, sensor, tank, objects, sigma_S_per_m, focus_m=None, **options):
            self.ev = pose_evaluator("psm", sensor, None, 1.0, objects)  # answers at every pose
            self.sensor = sensor

        def conductance(self, poses_, progress=False, wall_derivatives=False):
            solved.append(np.array(poses_))
            K = self.ev.conductance(poses_).K_S
            wiggle = 1 + 0.01 * np.sin(7 * poses_[:, 0])[:, None, None]
            return SimpleNamespace(K_S=K * wiggle, info={})   # no shape derivatives: the baseline does without

    monkeypatch.setattr(bem, "PoseSweep", CountingSweep)
    I = np.ones((len(poses), setup.sensor.n_electrodes - 1))
    obs = assemble(setup, poses, t, passes, I, np.random.default_rng(0), position_noise_m=0.0)
    store = AnchorStore(setup.sensor, setup.tank, folder=tmp_path)
    base = anchored_baseline(obs, 1e-4, store=store, check_discretisation=False)
    every = np.vstack(solved)
    assert len(every) == len(np.unique(np.round(every, 12), axis=0)) == base.n_bem_new  # no pose solved twice
    assert base.n_bem_new <= len(path)
    exact = np.isin(np.arange(len(poses)), base.anchors)
    for i in np.flatnonzero(exact):  # every sample at a solved pose has the BEM's K
        same = np.flatnonzero(np.all(poses == poses[i], axis=1))
        assert np.isin(same, base.anchors).all()
        assert np.allclose(base.K[same], base.K[i])


def test_estimated_error_bounds_the_true_one_and_vanishes_at_the_nodes():
    from electrosense.validation.diagnosis.anchored import estimated_error

    rng = np.random.default_rng(8)
    f = lambda X: np.column_stack([np.sin(3 * X[:, 0]) * np.cos(2 * X[:, 1]), np.exp(X[:, 0] * X[:, 1])])  # noqa: E731
    X = rng.uniform(0, 1, (30, 2))
    interp = RBFInterpolant(X, f(X))
    loo = np.abs(interp.leave_one_out)
    Z = rng.uniform(0.1, 0.9, (200, 2))
    true = np.abs(interp(Z) - f(Z))
    est = estimated_error(X, loo, Z)
    assert np.sqrt(np.mean(true**2)) <= np.sqrt(np.mean(est**2))
    near = X[:5] + 1e-4  # a fraction of a millimetre off an anchor (position noise of a second log)
    assert np.all(estimated_error(X, loo, near) < 0.05 * loo[:5].max(axis=0) + 1e-12)


def test_a_second_log_with_position_noise_reuses_the_anchors(tmp_path, monkeypatch):
    """A second log of the same path, its poses a tenth of a millimetre off the first's (the robot's position
    noise), is served by the first log's anchors: no new BEM pose, the estimated error within the target; and
    whichever base is chosen is the one with the smaller leave-one-out error."""
    from electrosense import bem
    from electrosense.validation.diagnosis.anchored import AnchorStore, anchored_baseline
    from electrosense.validation.diagnosis.blind import assemble
    from electrosense.validation.simulation.models import pose_evaluator

    rng = np.random.default_rng(5)
    setup = random_setup(rng, 4)
    poses, t, passes = random_passes(setup, rng, 2, 15)
    solved = []

    class SmoothSweep:  # a stand-in BEM: the PSM in the tank, smoothly changed
        def __init__(self, sensor, tank, objects, sigma_S_per_m, focus_m=None, **options):
            self.ev = pose_evaluator("psm", sensor, tank, 1.0, objects)

        def conductance(self, poses_, progress=False, wall_derivatives=False):
            solved.append(len(poses_))
            return SimpleNamespace(K_S=self.ev.conductance(poses_).K_S * (1 + 0.01 * np.sin(5 * poses_[:, 0]))[:, None, None],
                                   info={})

    monkeypatch.setattr(bem, "PoseSweep", SmoothSweep)
    I = np.ones((len(poses), setup.sensor.n_electrodes - 1))
    store = AnchorStore(setup.sensor, setup.tank, folder=tmp_path)
    first = anchored_baseline(assemble(setup, poses, t, passes, I, np.random.default_rng(0), position_noise_m=0.0),
                              3e-4, store=store, check_discretisation=False)
    assert first.n_bem_new >= 1 and first.rounds[-1]["base"] == first.base
    losses = {k[8:]: v for k, v in first.rounds[-1].items() if k.startswith("loo_rms_")}
    assert losses[first.base] == min(losses.values())
    solved.clear()
    second = anchored_baseline(assemble(setup, poses, t, passes, I, np.random.default_rng(1), position_noise_m=1e-4),
                               3e-4, store=store, check_discretisation=False)
    assert second.n_bem_new == 0 and not solved and second.n_cached >= first.n_bem_new
    assert second.interpolation_rms <= second.target
