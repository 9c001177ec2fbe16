"""The paper's conductivity correction: one scale factor fitted to the bench.

The currents of both models are proportional to the water's conductivity,
so a wrong conductivity multiplies every predicted current by one factor
``s``. The factor that brings a model onto the bench in the least-squares
sense of the relative errors,

    s = argmin sum_{p,k} ((s I_model[p,k] - I_bench[p,k]) / I_bench[p,k])^2
      = sum r / sum r^2,     r = I_model / I_bench,

gives the effective conductivity ``s * sigma_nominal``; the paper found it
about 2 % below the conductimeter's reading. After the correction the
relative error is (s I_model - I_bench) / I_bench, which is also the error of
the model against the *corrected bench* I_bench / s (the bench brought back to
the nominal conductivity, plotted in the resistance figure).

Uncertainty: the residuals along a path are correlated (a smooth model
error, not noise), so the standard error that assumes independent samples is
too small. The reported ``std_error`` is a delete-one-block jackknife over
contiguous blocks of poses (``n_blocks``, default 10), never less than the
independent-sample value, which is reported beside it as ``std_error_iid``.

Example
-------
>>> import numpy as np
>>> model = np.array([[1.0, 2.0], [1.5, 2.5], [1.2, 2.1]])
>>> fit = fit_conductivity_scale(model, 0.98 * model)
>>> round(fit.scale, 12), round(fit.percent, 9)
(0.98, -2.0)
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from electrosense.validation.comparison.metrics import relative_error

__all__ = ["ConductivityCorrection", "fit_conductivity_scale"]


@dataclass(frozen=True)
class ConductivityCorrection:
    """The fitted factor ``scale`` (model currents x scale ~ bench) and its uncertainty.

    Attributes
    ----------
    scale : float
        Least-squares factor on the model's currents (= sigma_effective / sigma_nominal).
    std_error : float
        Block-jackknife standard error of ``scale`` (at least ``std_error_iid``).
    std_error_iid : float
        Standard error assuming independent residuals.
    n_samples, n_blocks : int
        Currents used, and contiguous pose blocks of the jackknife.
    sigma_nominal_S_per_m, sigma_effective_S_per_m : float or None
        The logged conductivity and ``scale`` times it.
    """

    scale: float
    std_error: float
    std_error_iid: float
    n_samples: int
    n_blocks: int
    sigma_nominal_S_per_m: float | None = None
    sigma_effective_S_per_m: float | None = None

    @property
    def percent(self) -> float:
        """The correction in percent: 100 (scale - 1)."""
        return 100.0 * (self.scale - 1.0)

    def apply_to_model(self, model_A) -> np.ndarray:
        """Model currents at the effective conductivity."""
        return self.scale * np.asarray(model_A, dtype=float)

    def corrected_bench(self, bench_A) -> np.ndarray:
        """Bench currents brought back to the nominal conductivity: bench / scale."""
        return np.asarray(bench_A, dtype=float) / self.scale

    def to_dict(self) -> dict:
        d = asdict(self)
        d["percent"] = self.percent
        d["std_error_percent"] = 100.0 * self.std_error
        d["definition"] = (
            "scale minimising sum(((scale * I_model - I_bench) / I_bench)^2); "
            "sigma_effective = scale * sigma_nominal; std_error: delete-one-block jackknife over contiguous poses"
        )
        return d


def _scale(r: np.ndarray) -> float:
    return float(r.sum() / np.sum(r**2))


def fit_conductivity_scale(model_A, bench_A, sigma_nominal_S_per_m=None, n_blocks: int = 10) -> ConductivityCorrection:
    """Fit the one factor on the model's currents that best matches the bench.

    Parameters
    ----------
    model_A, bench_A : (P, m) arrays
        Receiver currents (A), poses in path order (blocks are contiguous poses).
    sigma_nominal_S_per_m : float, optional
        The log's conductivity, to report the effective one.
    n_blocks : int
        Number of contiguous pose blocks of the jackknife (at most P).
    """
    model = np.atleast_2d(np.asarray(model_A, dtype=float))
    bench = np.atleast_2d(np.asarray(bench_A, dtype=float))
    relative_error(model, bench)  # shape and finiteness checks, with clear messages
    r = model / bench
    if not np.any(r != 0):
        raise ValueError("the model's currents are all zero: no conductivity scale can be fitted")
    s = _scale(r)
    N = r.size
    resid = s * r - 1.0
    dof = max(N - 1, 1)
    se_iid = float(np.sqrt(np.sum(resid**2) / dof / np.sum(r**2)))
    P = r.shape[0]
    g = int(min(max(n_blocks, 2), P))
    if g >= 2:
        blocks = np.array_split(np.arange(P), g)
        leave_out = np.array([_scale(np.delete(r, b, axis=0)) for b in blocks])
        se_jack = float(np.sqrt((g - 1) / g * np.sum((leave_out - leave_out.mean()) ** 2)))
    else:
        se_jack = se_iid
    sigma_eff = None if sigma_nominal_S_per_m is None else float(s * sigma_nominal_S_per_m)
    return ConductivityCorrection(
        scale=s,
        std_error=max(se_jack, se_iid),
        std_error_iid=se_iid,
        n_samples=int(N),
        n_blocks=g,
        sigma_nominal_S_per_m=None if sigma_nominal_S_per_m is None else float(sigma_nominal_S_per_m),
        sigma_effective_S_per_m=sigma_eff,
    )
