"""The scene-fit engine's statistics (validation/diagnosis/scene_fit.py) against closed forms."""
import numpy as np
import pytest

from electrosense.validation.diagnosis.scene_fit import Unknown, fit_unknowns


@pytest.mark.parametrize("seed", [0, 1])
def test_a_gaussian_prior_gives_the_linear_posterior(seed):
    """Linear data ``y = X a + e`` (rows scaled to unit noise) and a Gaussian prior on one coefficient: the fit is
    the posterior's mean ``(X'X + P)^-1 (X'y + P m)`` to rounding, its standard errors the posterior's times the
    fit's own noise estimate; without data on it the coefficient stays at its prior mean, its standard error the
    prior's."""
    rng = np.random.default_rng(seed)
    n = 40
    X = np.c_[rng.normal(size=n), rng.normal(size=n), np.zeros(n)]      # the third coefficient unseen by the data
    a_true = np.array([0.7, -1.2, 0.0])
    y = X @ a_true + rng.standard_normal(n)
    mean, sd = np.array([0.0, -1.0, 0.3]), np.array([np.inf, 0.2, 0.5])
    us = [Unknown(f"a{k}", 0.0, -10, 10, 0.1, prior=None if np.isinf(s) else (m, s))
          for k, (m, s) in enumerate(zip(mean, sd))]
    fit = fit_unknowns(lambda a: X @ a - y, lambda a: X, us, max_nfev=50)
    P = np.diag(np.where(np.isinf(sd), 0.0, sd ** -2.0))
    A = X.T @ X + P
    posterior_mean = np.linalg.solve(A, X.T @ y + P @ np.where(np.isinf(sd), 0.0, mean))
    assert np.allclose(fit.x, posterior_mean, atol=1e-6)
    assert np.allclose(fit.se, fit.noise_rms * np.sqrt(np.diag(np.linalg.inv(A))), rtol=1e-4)
    assert fit.x[2] == pytest.approx(0.3) and fit.se[2] == pytest.approx(0.5 * fit.noise_rms)
    table = fit.table()
    assert table["a2"]["set_by_prior"] and not table["a0"].get("set_by_prior", False)
    assert any("a2" in d["unknowns"] for d in fit.not_separable)      # what the data alone leave open
