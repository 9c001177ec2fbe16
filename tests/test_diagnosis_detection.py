"""The detection test's false-alarm rate is the one it states, and it finds an effect below the per-sample noise."""
import numpy as np

from electrosense.validation.diagnosis.detection import heldout_improvement, null_draws, p_value, smooth_field


def _setup(rng, P=90, m=3):
    passes = [np.arange(0, 30), np.arange(30, 60), np.arange(60, 90)]
    folds = passes
    x = np.linspace(-1, 1, P)
    designs = {
        "common": np.ones((P * m, 1)),
        "slope": np.tile(x[:, None], (1, m)).reshape(-1, 1),
        "per_receiver": np.kron(np.ones((P, 1)), np.eye(m)),
    }
    # a "local" family: bumps at 20 places, one strength each
    centres = np.linspace(-1, 1, 20)
    bumps = np.exp(-0.5 * ((x[None, :] - centres[:, None]) / 0.05) ** 2)
    local = {"bump": np.repeat(bumps[:, :, None], m, axis=2).reshape(20, P * m)}
    return P, m, passes, folds, designs, local


def _observed(z, P, m, folds, designs, local):
    best = max(heldout_improvement(z[None], J, folds, P, m)[0, 0] for J in designs.values())
    return max(best, heldout_improvement(z[None], local["bump"], folds, P, m)[0].max())


def test_false_alarm_rate_is_the_stated_one():
    rng = np.random.default_rng(1)
    P, m, passes, folds, designs, local = _setup(rng)
    ratio = np.full((P, m), 0.8)  # model error of 0.8 noise, smooth along each pass
    null = null_draws(designs, folds, P, m, ratio, passes, rng=2, draws=400, local=local)
    threshold = np.quantile(null["max_improvement"], 0.95)
    # noise-only data from the same noise model, other draws
    trials = 300
    w = 1 / np.sqrt(1 + ratio**2)
    z = w[None] * (rng.standard_normal((trials, P, m)) + ratio[None] * smooth_field(rng, passes, m, trials))
    z = z.reshape(trials, -1)
    alarms = sum(_observed(zz, P, m, folds, designs, local) > threshold for zz in z)
    rate = alarms / trials
    assert abs(rate - 0.05) < 3 * np.sqrt(0.05 * 0.95 / trials) + 0.01, rate


def test_an_effect_below_the_per_sample_noise_is_found():
    rng = np.random.default_rng(3)
    P, m, passes, folds, designs, local = _setup(rng)
    ratio = np.zeros((P, m))
    null = null_draws(designs, folds, P, m, ratio, passes, rng=4, draws=400, local=local)
    x = np.linspace(-1, 1, P)
    signal = 0.6 * np.tile(x[:, None], (1, m)).ravel()  # RMS 0.35 of the noise per sample
    found = 0
    for _ in range(20):
        z = signal + rng.standard_normal(P * m)
        found += p_value(_observed(z, P, m, folds, designs, local), null["max_improvement"]) < 0.01
    assert found >= 18


def test_smooth_field_has_unit_variance():
    f = smooth_field(np.random.default_rng(0), [np.arange(50), np.arange(50, 80)], 2, 2000)
    assert abs(f.var() - 1) < 0.05
