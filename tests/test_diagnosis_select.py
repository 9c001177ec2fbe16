"""Selection on stand-in worlds: none at noise, the injected effect first, pairs, confusable warnings.

The world is the point-electrode stand-in with other electrode radii and
image shells than the stand-in the diagnosis fits with (fast; the blind suite
with BEM-made data is tests/test_diagnosis_blind.py).
"""
import numpy as np
import pytest

from electrosense.validation.diagnosis.blind import BlindSetup, assemble, blind_poses, world_currents
from electrosense.validation.diagnosis.forward import PointElectrodeSimulator
from electrosense.validation.diagnosis.pipeline import diagnose


@pytest.fixture(scope="module")
def world():
    setup = BlindSetup()
    poses, t, passes = blind_poses(32)
    w = PointElectrodeSimulator(setup.sensor, setup.sigma_S_per_m, radius_factor=0.68, shells=3)
    K0 = w(poses, setup.tank, (), None)
    fitter = PointElectrodeSimulator(setup.sensor, setup.sigma_S_per_m)
    return setup, poses, t, passes, w, K0, fitter


def _run(world, seed, effect=None, strength=None, **output):
    setup, poses, t, passes, w, K0, fitter = world
    I = world_currents(w, setup, poses, effect, strength)
    obs = assemble(setup, poses, t, passes, I, np.random.default_rng(seed), **output)
    return diagnose(obs, K_base=K0, effect_model=fitter)


def test_noise_only_gives_none(world):
    """At the detection test's false-alarm rate (1 %): at most one of six noise-only logs names an effect
    (a second one has a chance of 0.15 %), and every log's gap is at the noise."""
    runs = [_run(world, seed) for seed in range(10, 16)]
    assert sum(d.chosen == ["none"] for d in runs) >= 5, [d.chosen for d in runs]
    assert all(d.gap_before < 1.5 * d.noise for d in runs)
    assert all(d.detection["alpha"] == 0.01 for d in runs)


def test_conductivity_is_named_and_warned_against_a_common_gain(world):
    d = _run(world, 11, conductivity=0.02)
    assert d.chosen == ["conductivity"]
    assert d.gap_after < 0.2 * d.gap_before
    pair = next(p for p in d.confusable if set(p["pair"]) == {"conductivity", "channel_gain"})
    assert pair["angle_deg"] < 1 and "conductimeter" in pair["separate_by"]
    best = d.ranking[0]
    est = best.fit.params()["conductivity"]["sigma_rel_change"]
    sd = best.fit.uncertainty()["conductivity"]["sigma_rel_change"]
    assert abs(est - 0.02) < 5 * sd + 1e-4


def test_drift_with_logged_temperature_follows_it(world):
    d = _run(world, 12, drift_per_hour=0.05, log_temperature=True)
    assert d.chosen[0] == "temperature_drift"
    p = d.final.fit.params()["temperature_drift"]
    # either form describes it: sigma following the logged temperature at 2 %/K, or drifting 5 %/h
    if "alpha_per_K" in p:
        assert p["alpha_per_K"] == pytest.approx(0.02, rel=0.2)
    else:
        assert p["drift_per_hour"] == pytest.approx(0.05, rel=0.2)


def test_a_pair_is_found_in_full(world):
    d = _run(world, 13, "tank_size", {"Lx_m": 0.97}, gains=[0.01, -0.01, 0.0])
    assert set(d.chosen[:2]) == {"tank_size", "channel_gain"}
    assert d.gap_after < 0.2 * d.gap_before
