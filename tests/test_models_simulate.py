"""electrosense.validation.simulation.models: one door from a model name to conductance matrices for many poses."""
from __future__ import annotations

import numpy as np
import pytest

from electrosense import bem, psm
from electrosense.meshes.sensor import preset
from electrosense.meshes.tank import Tank
from electrosense.validation.simulation import models
from electrosense.validation.simulation.models import ModelError, calibrated_psm, pose_evaluator, simulate
from electrosense.validation.simulation.sweep import line_poses, parse_grid, run_sweep

TANK = Tank((1.0, 1.0, 1.0))
SIGMA = 0.0354


@pytest.fixture(scope="module")
def model4():
    """A symmetric 4-sphere PSM (the paper's fitted proportions)."""
    return psm.PolySphericalModel(
        radii_m=np.array([0.0072, 0.0074, 0.0074, 0.0072]),
        centres_m=np.array([[0.11695, 0, 0], [0.03845, 0, 0], [-0.03845, 0, 0], [-0.11695, 0, 0]]),
        emitter=4,
    )


def test_simulate_psm_is_the_psm(model4):
    poses = line_poses((-0.3, 0.0), (0.3, 0.1), 31, yaw_rad=0.4)
    C = simulate("psm", preset("angels-4"), poses, TANK, SIGMA, psm_model=model4, images="paper8")
    direct = psm.conductance(model4, poses, SIGMA, tank=TANK, images="paper8")
    np.testing.assert_array_equal(C.K_S, direct.K_S)
    assert C.batch_shape == (31,) and C.emitter == 4 and C.sigma_S_per_m == SIGMA


def test_psm_model_file_is_accepted(model4, tmp_path):
    model4.save(tmp_path / "m.json")
    poses = np.array([[0.1, 0.05, 0.0, 0.0]])
    a = simulate("psm", preset("angels-4"), poses, None, SIGMA, psm_model=tmp_path / "m.json")
    b = simulate("psm", preset("angels-4"), poses, None, SIGMA, psm_model=model4)
    np.testing.assert_array_equal(a.K_S, b.K_S)


def test_chunked_psm_sweep_equals_one_call(model4):
    """The image series is settled once over the whole sweep, so chunks give exactly one call's numbers."""
    poses = parse_grid("-0.3:0.3:9,-0.35:0.35:8,0:1.57:2").poses
    ev = pose_evaluator("psm", preset("angels-4"), TANK, SIGMA, psm_model=model4, poses=poses)
    assert ev.image_shells is not None
    swept = run_sweep(ev, poses, workers=1, chunk_poses=10, progress=False).conductance
    np.testing.assert_array_equal(swept.K_S, ev.conductance(poses).K_S)
    adaptive = psm.conductance(model4, poses, SIGMA, tank=TANK)  # the PSM's own choice over all poses
    np.testing.assert_allclose(swept.K_S, adaptive.K_S, rtol=1e-9, atol=1e-9 * np.abs(adaptive.K_S).max())


@pytest.mark.parametrize("call, message", [
    (lambda m: simulate("fem", preset("angels-4"), np.zeros((1, 4)), None, SIGMA), "unknown model 'fem'"),
    (lambda m: simulate("psm", preset("angels-2"), np.zeros((1, 4)), None, SIGMA, psm_model=m),
     "the PSM has 4 spheres but the sensor 'angels-2' has 2 electrodes"),
    (lambda m: simulate("psm", preset("angels-4").with_emitter(1), np.zeros((1, 4)), None, SIGMA, psm_model=m),
     "emitter is electrode 4, the sensor's is 1"),
    (lambda m: simulate("psm", preset("angels-4"), np.zeros((1, 4)), None, SIGMA, psm_model=m, quadrature_order=3),
     "quadrature_order are BEM options"),
    (lambda m: simulate("bem", preset("angels-4"), np.zeros((1, 4)), None, SIGMA, psm_model=m), "model is 'bem'"),
    (lambda m: simulate("psm", preset("angels-4"), np.zeros((1, 4)), None, -1.0, psm_model=m), "positive conductivity"),
    (lambda m: simulate("psm", preset("angels-4"), np.zeros((1, 4)), None, SIGMA, psm_model="missing.json"),
     "missing.json does not exist"),
])
def test_bad_requests_are_named(model4, call, message):
    with pytest.raises(ModelError, match=message):
        call(model4)


def test_calibrated_psm_is_computed_once_and_cached_by_sensor_and_code(model4, tmp_path, monkeypatch):
    """A reference made by a known PSM is fitted back to it; the second request reads the cache."""
    monkeypatch.setenv("ESENSE_CACHE_DIR", str(tmp_path))
    calls = []

    def reference_bem(scene, sigma_S_per_m, contact_impedance_ohm_m2=None, edge_length_m=None, **_):
        calls.append((scene.sensor.name, edge_length_m))
        assert scene.tank is None and not scene.objects  # free space, as the paper calibrates
        return psm.conductance(model4, np.zeros((1, 4)), sigma_S_per_m)[0]

    monkeypatch.setattr(bem, "conductance_matrix", reference_bem)
    sensor = preset("angels-4")
    first = calibrated_psm(sensor, edge_length_m=0.004)
    np.testing.assert_allclose(first.radii_m, model4.radii_m, rtol=1e-4)
    np.testing.assert_allclose(first.centres_m, model4.centres_m, atol=1e-6)
    assert first.electrode_areas_m2 is not None  # recorded for the contact impedance
    second = calibrated_psm(sensor, edge_length_m=0.004)
    np.testing.assert_array_equal(second.radii_m, first.radii_m)
    assert len(calls) == 1
    calibrated_psm(sensor, edge_length_m=0.003)  # another mesh is another reference
    monkeypatch.setattr(models, "code_version", lambda: "electrosense test src changed")
    calibrated_psm(sensor, edge_length_m=0.004)  # edited code is never served stale results
    assert calls == [("angels-4", 0.004), ("angels-4", 0.003), ("angels-4", 0.004)]
    # a damaged cache entry is recomputed, not trusted
    for path in (tmp_path / "psm").glob("*.json"):
        path.write_text("{not json")
    calibrated_psm(sensor, edge_length_m=0.004)
    assert len(calls) == 4


def test_calibration_layouts_follow_the_data():
    assert models.calibration_layout(preset("angels-4")) == {"symmetric": True, "fix_length_m": None}
    assert models.calibration_layout(preset("angels-2")) == {"symmetric": True, "fix_length_m": 0.2}


@pytest.mark.skipif(not hasattr(bem, "PoseSweep"), reason="electrosense.bem.PoseSweep not there yet")
def test_simulate_bem_matches_the_single_scene_solver():
    from electrosense.meshes.pose import Pose
    from electrosense.meshes.scene import Scene

    sensor = preset("angels-2")
    poses = np.array([[0.0, 0.0, 0.0, 0.0], [0.05, 0.02, 0.0, 1.0]])
    C = simulate("bem", sensor, poses, None, SIGMA, edge_length_m=0.01)
    for pose, K in zip(poses, C.K_S):
        single = bem.conductance_matrix(Scene(sensor, Pose(*pose)), SIGMA, edge_length_m=0.01)
        np.testing.assert_allclose(K, single.K_S, rtol=1e-6, atol=1e-9 * np.abs(single.K_S).max())
    # unbounded water: translation and rotation change nothing
    np.testing.assert_allclose(C.K_S[1], C.K_S[0], rtol=1e-6)


@pytest.mark.slow
def test_psm_calibrated_on_the_bem_reproduces_the_free_space_bem(tmp_path, monkeypatch):
    monkeypatch.setenv("ESENSE_CACHE_DIR", str(tmp_path))
    sensor = preset("angels-4")
    C = simulate("psm", sensor, np.zeros((1, 4)), None, SIGMA)
    ref = bem.conductance_matrix(__import__("electrosense.meshes.scene", fromlist=["Scene"]).Scene(sensor), SIGMA)
    assert np.abs(C.S_S[0] - ref.S_S).max() / np.abs(ref.S_S).max() < 0.01
