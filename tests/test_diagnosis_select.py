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


def test_a_bem_re_solve_is_skipped_only_where_it_cannot_change_the_answer(monkeypatch):
    """The secant's bound: each current may change by up to the candidate's own change of it (a quarter for walls
    and depth), so the samples it does not touch keep their held-out gap."""
    from types import SimpleNamespace

    import electrosense.validation.diagnosis.fitting as fitting
    from electrosense.validation.diagnosis.pipeline import secant_cannot_overtake

    P, noise = 100, 1e-3
    local = np.r_[np.full(10, 5 * noise), np.zeros(P - 10)][:, None]   # an object: 10 samples see it
    everywhere = np.full((P, 1), 5 * noise)                            # a depth: every sample
    bench = np.zeros((P, 1))

    class Stub:
        obs = SimpleNamespace(n_poses=P)
        weight = np.ones((P, 1))

        @staticmethod
        def relative_residual(I, idx):
            return bench[idx] - I

    def candidate(name, change):
        monkeypatch.setattr(fitting, "predict", lambda pb, eff, theta, idx: change[idx] * float(np.any(theta)))
        return SimpleNamespace(name=name, effects=(), fit=SimpleNamespace(theta=np.array([1.0])),
                               heldout=np.full((P, 1), 3 * noise), n_params=1)

    cannot, bound = secant_cannot_overtake(Stub(), candidate("unmodelled_object", local), 200.0, noise)
    assert cannot and bound == pytest.approx(90 * 9 + np.log(P))
    cannot, bound = secant_cannot_overtake(Stub(), candidate("unmodelled_object", everywhere), 200.0, noise)
    assert not cannot and bound == pytest.approx(np.log(P))
    # a depth's re-solve moves its currents by a quarter of its change at most: 3 - 1.25 noise left everywhere
    cannot, bound = secant_cannot_overtake(Stub(), candidate("water_depth", everywhere), 200.0, noise)
    assert cannot and bound == pytest.approx(P * 1.75**2 + np.log(P))
