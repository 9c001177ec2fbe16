"""The diagnosis machinery on a stand-in forward model: effects, fits, noise, folds, confusability."""
import numpy as np
import pytest

from electrosense.meshes.sensor import preset
from electrosense.validation.diagnosis.blind import BlindSetup, assemble, blind_poses, world_currents
from electrosense.validation.diagnosis.effects import EFFECT_NAMES, Problem, library, object_sphere
from electrosense.validation.diagnosis.fitting import (
    cross_validate,
    fit,
    make_folds,
    noise_level,
    predict,
    subspace_angle_deg,
)
from electrosense.validation.diagnosis.forward import (
    PointElectrodeSimulator,
    electrode_areas_m2,
    receiver_currents,
    series_contact,
    sphere_dipole_m3,
)
from electrosense.validation.diagnosis.observations import DiagnosisInputError, Observations


@pytest.fixture(scope="module")
def setup():
    return BlindSetup()


@pytest.fixture(scope="module")
def sim(setup):
    return PointElectrodeSimulator(setup.sensor, setup.sigma_S_per_m)


@pytest.fixture(scope="module")
def trajectory():
    return blind_poses(24)


def _problem(setup, sim, trajectory, I_world, rng, **kw):
    poses, t, passes = trajectory
    obs = assemble(setup, poses, t, passes, I_world, rng, **kw)
    return Problem(obs, sim(obs.poses, obs.tank, ()), sim)


def test_library_has_exactly_the_issue_names(setup):
    lib = library(Observations(np.zeros((8, 4)), np.ones((8, 3)), setup.sensor, setup.tank, 0.0354))
    assert tuple(lib) == EFFECT_NAMES
    unbounded = library(Observations(np.zeros((8, 4)), np.ones((8, 3)), setup.sensor, None, 0.0354))
    assert "water_depth" not in unbounded and "tank_size" not in unbounded


def test_series_contact_two_electrodes_adds_resistances():
    g = 0.01  # S between two electrodes
    K = np.array([[g, -g], [-g, g]])
    Z = np.array([30.0, 70.0])
    Kc = series_contact(K, Z)
    assert np.allclose(Kc, Kc.T) and np.allclose(Kc.sum(axis=1), 0)
    assert Kc[0, 0] == pytest.approx(1 / (1 / g + Z.sum()))
    assert np.allclose(series_contact(K, np.zeros(2)), K)


def test_electrode_areas_match_the_geometry():
    s = preset("angels-4")
    A = electrode_areas_m2(s)
    r = s.radius_m
    # Archimedes: a spherical cap (or a band of the cylinder) of axial height h has area 2 pi r h
    for a, e in zip(A, s.electrodes):
        assert a == pytest.approx(2 * np.pi * r * (e.x_max_m - e.x_min_m))
    # and the meshed electrodes agree (independent geometry)
    from electrosense.meshes.sensor_mesh import mesh_sensor

    assert A == pytest.approx(mesh_sensor(s).electrode_areas_m2(), rel=0.02)


def test_stand_in_is_a_conductance_and_walls_raise_resistance(sim, setup):
    poses = np.array([[0.0, 0, 0, 0], [0.35, 0, 0, 0]])
    K = sim(poses, setup.tank, ())
    assert np.allclose(K, np.swapaxes(K, 1, 2)) and np.allclose(K.sum(axis=-1), 0, atol=1e-15)
    I = receiver_currents(K, setup.sensor.emitter)
    assert np.all(I > 0)
    free = receiver_currents(sim(poses[:1], None, ()), setup.sensor.emitter)
    # Rayleigh: insulating walls take conductance away from the emitter-to-receivers path (receivers shorted)
    assert I[0].sum() < free[0].sum()
    assert I[1].sum() < I[0].sum()  # more so near a wall


def test_the_effect_models_take_the_balls_and_leave_a_pole_or_a_box_to_the_baseline(setup, trajectory):
    """The PSM's object term is a ball's dipole: a pole or a box in the scene (a tank map's fixed objects, a log's
    meta line) is left out of the effect model, whose changes are then those without it, not refused."""
    from electrosense.meshes.objects import Box, Cylinder, Sphere
    from electrosense.validation.diagnosis.forward import PSMEffectModel
    from electrosense.validation.diagnosis.pipeline import default_effect_model_from

    poses = trajectory[0][:24]   # the first pass: y = 0, z = 0
    ball = Sphere((0.0, 0.08, 0.0), np.inf, radius_m=0.02)
    others = (Cylinder((0.2, -0.15, 0.0), 0.0, radius_m=0.01, height_m=0.05),
              Box((-0.2, -0.15, 0.0), 0.0, size_m=(0.03, 0.03, 0.03)))
    for model in (PointElectrodeSimulator(setup.sensor, setup.sigma_S_per_m), PSMEffectModel(setup.sensor,
                  setup.sigma_S_per_m), default_effect_model_from(setup.sensor, setup.sigma_S_per_m,
                                                                  PSMEffectModel(setup.sensor, 1.0).model)):
        with_ball = model(poses, setup.tank, (ball,))
        assert np.array_equal(model(poses, setup.tank, (ball, *others)), with_ball)
        assert not np.allclose(with_ball, model(poses, setup.tank, ()), rtol=1e-6)


def test_sphere_dipole_strength_matches_its_parameter():
    for m in (2e-6, -3e-6):
        sphere = object_sphere((0.1, 0.0, 0.0, m), 0.0354)
        assert sphere_dipole_m3(sphere, 0.0354) == pytest.approx(m)
    assert object_sphere((0, 0, 0, 0.0), 0.0354) is None


def test_output_effects_are_exact_scalings(setup, sim, trajectory):
    rng = np.random.default_rng(0)
    I0 = world_currents(sim, setup, trajectory[0], None)
    pb = _problem(setup, sim, trajectory, I0, rng)
    lib = library(pb.obs)
    idx = np.arange(pb.obs.n_poses)
    base = pb.I_base
    assert np.allclose(predict(pb, lib["conductivity"], [0.03], idx), 1.03 * base)
    g = np.array([0.01, -0.02, 0.005])
    assert np.allclose(predict(pb, lib["channel_gain"], g, idx), base * (1 + g))
    drift = predict(pb, lib["temperature_drift"][:1], [0.036], idx)
    t_h = (pb.obs.t_s - pb.obs.t_s.mean()) / 3600
    assert np.allclose(drift, base * (1 + 0.036 * t_h)[:, None])
    # a contact impedance in series can only lower every current
    assert np.all(predict(pb, lib["contact_impedance"][:1], [0.01], idx) < base)


def test_pose_offset_and_water_depth_change_the_scene_as_stated(setup, sim, trajectory):
    rng = np.random.default_rng(1)
    pb = _problem(setup, sim, trajectory, world_currents(sim, setup, trajectory[0], None), rng)
    lib = library(pb.obs)
    idx = np.arange(5)
    sc = lib["pose_offset"][0].apply(np.array([0.01, -0.02, 0.1]), pb.nominal(idx), pb, idx)
    p0 = pb.obs.poses[idx]
    c, s = np.cos(0.1), np.sin(0.1)
    assert np.allclose(sc.poses[:, 0], c * p0[:, 0] - s * p0[:, 1] + 0.01)
    assert np.allclose(sc.poses[:, 3], p0[:, 3] + 0.1)
    sc = lib["water_depth"][0].apply(np.array([-0.2]), pb.nominal(idx), pb, idx)
    assert sc.tank.water_depth_m == pytest.approx(0.8)
    # height above the floor unchanged
    assert np.allclose(sc.poses[:, 2] - sc.tank.floor_z_m, p0[:, 2] - setup.tank.floor_z_m)
    sc = lib["water_depth"][1].apply(np.array([0.1]), pb.nominal(idx), pb, idx)
    assert np.allclose(sc.poses[:, 2] - sc.tank.floor_z_m, p0[:, 2] - setup.tank.floor_z_m - 0.1)


def test_noise_level_recovers_white_noise_under_a_smooth_gap():
    rng = np.random.default_rng(2)
    x = np.linspace(-1, 1, 300)
    r = 0.01 * x[:, None] ** 2 + 5e-4 * rng.standard_normal((300, 3))
    assert noise_level(r, [np.arange(300)]) == pytest.approx(5e-4, rel=0.15)


def test_folds_partition_the_samples(setup, trajectory):
    poses, t, passes = trajectory
    obs = Observations(poses, np.ones((len(poses), 3)), setup.sensor, setup.tank, 0.0354, t_s=t, passes=passes)
    folds = make_folds(obs)
    allidx = np.concatenate(folds)
    assert len(allidx) == obs.n_poses and len(np.unique(allidx)) == obs.n_poses
    assert all(len(np.intersect1d(f, np.flatnonzero(passes == p))) > 0 for f in folds for p in (0, 1))
    three = Observations(np.vstack([poses, poses[:10]]), np.ones((len(poses) + 10, 3)), setup.sensor, setup.tank,
                         0.0354, passes=np.concatenate([passes, np.full(10, 2)]))
    folds = make_folds(three)
    assert len(folds) == 3 and all(len(np.unique(three.passes[f])) == 1 for f in folds)


def test_fit_recovers_a_geometric_effect_with_honest_uncertainty(setup, sim, trajectory):
    rng = np.random.default_rng(3)
    truth = {"Lx_m": 0.97}
    I = world_currents(sim, setup, trajectory[0], "tank_size", truth)
    pb = _problem(setup, sim, trajectory, I, rng)
    lib = library(pb.obs)
    f = fit(pb, lib["tank_size"][:1], np.arange(pb.obs.n_poses), noise=5e-4)
    est, sd = f.params()["tank_size"]["dLx_m"], f.uncertainty()["tank_size"]["dLx_m"]
    assert abs(est - (-0.03)) < max(4 * sd, 1e-4)
    assert f.train_rms < 1.3 * 5e-4
    heldout, thetas = cross_validate(pb, lib["tank_size"][:1], make_folds(pb.obs), full=f)
    assert np.sqrt(np.mean(heldout**2)) < 1.5 * 5e-4
    assert len(thetas) == len(make_folds(pb.obs))


def test_sensitivity_angles_tell_confusable_candidates(setup, sim, trajectory):
    rng = np.random.default_rng(4)
    pb = _problem(setup, sim, trajectory, world_currents(sim, setup, trajectory[0], None), rng, conductivity=0.02)
    lib = library(pb.obs)
    idx = np.arange(pb.obs.n_poses)
    a = fit(pb, lib["conductivity"], idx)
    b = fit(pb, lib["channel_gain"], idx)
    c = fit(pb, lib["pose_offset"][:1], idx)
    assert subspace_angle_deg(a.jac, a.jac) < 1e-3
    assert subspace_angle_deg(a.jac, b.jac) < 1.0  # a common gain is a common scale
    assert subspace_angle_deg(a.jac, c.jac) > 20.0


def test_observations_refuse_bad_input(setup):
    with pytest.raises(DiagnosisInputError, match="receivers"):
        Observations(np.zeros((10, 4)), np.ones((10, 2)), setup.sensor, setup.tank, 0.0354)
    with pytest.raises(DiagnosisInputError, match="non-finite"):
        Observations(np.zeros((10, 4)), np.full((10, 3), np.nan), setup.sensor, setup.tank, 0.0354)
    with pytest.raises(DiagnosisInputError, match="too few"):
        Observations(np.zeros((3, 4)), np.ones((3, 3)), setup.sensor, setup.tank, 0.0354)


@pytest.mark.parametrize("seed", [3, 11])
def test_effect_model_image_shells_converged_in_changes(seed):
    """The PSM effect model's image series, chosen on changes, is right to its tolerance against a much longer one
    (random sensor, tank and passes near the walls)."""
    from electrosense.meshes.tank import Tank
    from electrosense.validation.diagnosis.forward import IMAGE_CHANGE_TOLERANCE, PSMEffectModel
    from electrosense.validation.diagnosis.unseen import random_passes, random_setup

    rng = np.random.default_rng(seed)
    s = random_setup(rng)
    poses, _, _ = random_passes(s, rng, n_passes=2, per_pass=15)
    m = PSMEffectModel(s.sensor, s.sigma_S_per_m)
    shells = m.choose_image_shells(poses, s.tank)
    lx, ly, lz = s.tank.size_m
    changed = Tank((lx + 0.006, ly, lz), s.tank.water_depth_m - 0.004)   # not one of its probes
    off = ~np.eye(m.model.n, dtype=bool)

    def change(n):
        return m._K(poses, changed, image_shells=n)[:, off] / m._K(poses, s.tank, image_shells=n)[:, off] - 1

    ref = change(28)
    assert np.max(np.abs(change(shells) - ref)) <= 2 * IMAGE_CHANGE_TOLERANCE * np.max(np.abs(ref))
