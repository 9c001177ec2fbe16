"""A scene's unknowns fitted to measurements: bounded nonlinear least squares, standard errors, and what the data
cannot separate.

The engine behind the real-tank studies (KTC2023, the Ottawa phantoms): a
forward model maps named unknowns (:class:`Unknown`: a value, bounds, a
typical step) to predicted data; :func:`fit_unknowns` minimises the sum of
squared residuals (:func:`scipy.optimize.least_squares`, trust region with
bounds) with a Jacobian that the caller supplies (analytic where it is cheap,
finite differences where a parameter moves the geometry).

The statistics (:func:`uncertainty`): the noise model is independent residuals of one variance, estimated from
the fit's own residuals, ``s^2 = |r|^2 / (n - p)`` (the data's
linear floor says how far that is from white); the covariance is
``s^2 (J^T J)^+`` in the unknowns' scaled coordinates (with an unknown's Gaussian prior, :attr:`Unknown.prior`,
as one more row of ``r`` and ``J``: a maximum a posteriori fit, the standard errors the posterior's). Directions of ``J``
whose singular value is below ``1e-3`` of the largest (a change of the
unknowns that moves the data by less than a thousandth of the best
determined one) are not determined by the data: they are named
(:func:`not_separable`, the unknowns that make up each, with their weights)
and left out of the pseudo-inverse, so the standard errors given are those
of the determined part; an unknown whose standard error exceeds its own
size, or that sits on a bound, is flagged too. Correlations above 0.95 in
magnitude are listed.

Example
-------
A line through points, its slope and intercept with their standard errors, and an unknown the data never see:

>>> x = np.linspace(0, 1, 20); y = 2 * x + 1 + 0.01 * np.sin(7 * x)
>>> us = [Unknown("slope", 1.0, -10, 10), Unknown("intercept", 0.0, -10, 10), Unknown("unseen", 0.5, 0, 1)]
>>> fit = fit_unknowns(lambda v: v[0] * x + v[1] - y, lambda v: np.c_[x, np.ones_like(x), 0 * x], us)
>>> round(fit.values["slope"], 1), round(fit.values["intercept"], 1), fit.not_separable[0]["unknowns"]
(2.0, 1.0, {'unseen': 1.0})
>>> bool(fit.se[0] < 0.01), bool(np.isnan(fit.se[2]))
(True, True)
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy.optimize import least_squares

__all__ = ["Unknown", "SceneFit", "fit_unknowns", "prior_rows", "set_by_prior", "uncertainty", "not_separable"]

#: singular values below this fraction of the largest: directions the data do not determine
UNDETERMINED = 1e-3
#: correlations above this magnitude are listed
CORRELATED = 0.95


@dataclass(frozen=True)
class Unknown:
    """A named unknown: start ``value``, bounds, ``step`` (its typical size, for scaling), unit and meaning;
    ``prior``: (mean, standard deviation) of what is known before the data (a description's value and its
    tolerance), a Gaussian that :func:`fit_unknowns` adds as one residual row, ``(x - mean) / sd``, in the
    units of the data's rows (which the caller scales to one noise standard deviation)."""

    name: str
    value: float
    lower: float = -np.inf
    upper: float = np.inf
    step: float = 1.0
    unit: str = ""
    meaning: str = ""
    prior: tuple | None = None


def prior_rows(unknowns: Sequence[Unknown], x, fixed: Sequence[str] = ()) -> np.ndarray:
    """The Gaussian priors' residual rows ``(x - mean) / sd`` of the free unknowns that have one.

    >>> prior_rows([Unknown("a", 0.0, prior=(1.0, 0.5)), Unknown("b", 0.0)], np.array([2.0, 7.0]))
    array([2.])
    """
    return np.array([(v - u.prior[0]) / u.prior[1] for u, v in zip(unknowns, np.asarray(x, float))
                     if u.prior is not None and u.name not in set(fixed)], float)


@dataclass
class SceneFit:
    """Fitted values, standard errors (NaN where undetermined), correlations, what is not separable, residuals."""

    names: list
    x: np.ndarray
    se: np.ndarray
    residual: np.ndarray
    jacobian: np.ndarray
    not_separable: list = field(default_factory=list)
    correlated: list = field(default_factory=list)
    at_bound: list = field(default_factory=list)
    noise_rms: float = float("nan")
    nfev: int = 0
    prior_sd: dict = field(default_factory=dict)

    @property
    def values(self) -> dict:
        return {n: float(v) for n, v in zip(self.names, self.x)}

    def table(self, units: dict | None = None) -> dict:
        """{name: {value, se, unit}} for metrics files; with a prior also its ``prior_sd`` and ``set_by_prior``
        (the standard error above 0.7 of the prior's, both scaled by the fit's scatter ``noise_rms`` as every
        standard error is: the data narrow it by less than 30 %)."""
        units = units or {}
        out = {n: {"value": float(v), "se": None if not np.isfinite(s) else float(s), "unit": units.get(n, "")}
               for n, v, s in zip(self.names, self.x, self.se)}
        for n, sd in self.prior_sd.items():
            out[n].update(prior_sd=float(sd), set_by_prior=set_by_prior(out[n]["se"], sd, self.noise_rms))
        return out


def set_by_prior(se, prior_sd: float, noise_rms: float) -> bool:
    """Whether an unknown with a prior is set by it rather than by the data: its standard error still above 0.7 of
    the prior's, both scaled by the fit's scatter as every standard error is (the data narrow the prior by less
    than 30 %), or none at all (``None``/NaN: a direction the data do not determine, or the unknown held; the
    prior's row is then what holds it).

    >>> set_by_prior(0.9, 1.0, 1.0), set_by_prior(0.5, 1.0, 1.0), set_by_prior(None, 1.0, 1.0)
    (True, False, True)
    """
    return bool(se is None or not np.isfinite(se) or se > 0.7 * noise_rms * prior_sd)


def not_separable(J: np.ndarray, names: Sequence[str], scale: np.ndarray, rtol: float = UNDETERMINED) -> list:
    """The directions (in the unknowns' typical steps) that move the data by less than ``rtol`` of the best determined
    one: each as the unknowns that make it up (weights of its unit vector, the largest first, those above 0.1)."""
    A = J * scale[None]
    if A.size == 0:
        return []
    _, s, vt = np.linalg.svd(A, full_matrices=False)
    out = []
    for sv, v in zip(s, vt):
        if sv < rtol * s[0]:
            big = np.argsort(-np.abs(v))
            comp = {names[i]: round(float(v[i]), 3) for i in big if abs(v[i]) > 0.1}
            out.append({"relative_singular_value": float(sv / s[0]), "unknowns": comp})
    # directions with no singular value at all (more unknowns than data)
    return out


def uncertainty(J: np.ndarray, residual: np.ndarray, scale: np.ndarray, rtol: float = UNDETERMINED):
    """Standard errors (NaN for unknowns that lie mostly in undetermined directions), correlation matrix and the
    residual noise ``s``."""
    n, p = J.shape
    dof = max(n - p, 1)
    s2 = float(residual @ residual) / dof
    A = J * scale[None]
    u, sv, vt = np.linalg.svd(A, full_matrices=False)
    keep = sv >= rtol * sv[0] if len(sv) else np.zeros(0, bool)
    inv = (vt[keep].T / sv[keep] ** 2) @ vt[keep]
    cov = s2 * inv * np.outer(scale, scale)
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    # an unknown whose unit vector lies mostly in the undetermined directions has no standard error
    und = (vt[~keep] ** 2).sum(axis=0) if (~keep).any() else np.zeros(p)
    se = np.where(und > 0.5, np.nan, se)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(np.sqrt(np.diag(cov)), np.sqrt(np.diag(cov)))
    return se, corr, float(np.sqrt(s2))


def fit_unknowns(residual_fn: Callable[[np.ndarray], np.ndarray], jacobian_fn: Callable[[np.ndarray], np.ndarray],
                 unknowns: Sequence[Unknown], max_nfev: int = 30, fixed: Sequence[str] = (), loss: str = "linear",
                 f_scale: float = 1.0) -> SceneFit:
    """Fit the unknowns (those named in ``fixed`` kept at their start value) by bounded least squares.

    ``residual_fn(x)`` (n,) and ``jacobian_fn(x)`` (n, p) take the full vector
    of every unknown's value, in the order given. ``loss``, ``f_scale``: those of
    :func:`scipy.optimize.least_squares` (``"soft_l1"`` discounts residuals beyond ``f_scale``: a few
    outlying rows); the standard errors then come from its reweighted Jacobian and the raw residuals' scatter
    (an overestimate where rows were discounted).
    """
    names = [u.name for u in unknowns]
    x0 = np.array([u.value for u in unknowns], float)
    lo = np.array([u.lower for u in unknowns], float)
    hi = np.array([u.upper for u in unknowns], float)
    step = np.array([u.step for u in unknowns], float)
    free = np.array([n not in set(fixed) for n in names])
    x0 = np.clip(x0, lo, hi)
    # the priors' rows: d row / d x = 1 / sd in the unknown's column
    with_prior = [k for k, u in enumerate(unknowns) if u.prior is not None and free[k]]
    P = np.zeros((len(with_prior), len(names)))
    P[np.arange(len(with_prior)), with_prior] = [1.0 / unknowns[k].prior[1] for k in with_prior]

    def full(xf):
        x = x0.copy()
        x[free] = xf
        return x

    def rows(xf):
        x = full(xf)
        return np.concatenate([residual_fn(x), prior_rows(unknowns, x, fixed)])

    res = least_squares(rows, x0[free], jac=lambda xf: np.vstack([jacobian_fn(full(xf)), P])[:, free],
                        bounds=(lo[free], hi[free]), x_scale=step[free], max_nfev=max_nfev, method="trf",
                        loss=loss, f_scale=f_scale)
    x = full(res.x)
    J = res.jac
    n_data = len(res.fun) - len(with_prior)     # what the data alone leave undetermined, before any prior
    se_f, corr, noise = uncertainty(J, res.fun, step[free])
    se = np.full(len(names), np.nan)
    se[free] = se_f
    fnames = [n for n, f in zip(names, free) if f]
    corr_list = []
    for i in range(len(fnames)):
        for j in range(i + 1, len(fnames)):
            if np.isfinite(corr[i, j]) and abs(corr[i, j]) > CORRELATED:
                corr_list.append({"unknowns": [fnames[i], fnames[j]], "correlation": round(float(corr[i, j]), 3)})
    span = np.where(np.isfinite(hi - lo), hi - lo, np.inf)
    at_bound = [n for n, v, a, b, sp, f in zip(names, x, lo, hi, span, free)
                if f and (abs(v - a) <= 1e-6 * min(sp, 1e6) + 1e-12 or abs(v - b) <= 1e-6 * min(sp, 1e6) + 1e-12)]
    return SceneFit(names, x, se, res.fun, J, not_separable(J[:n_data], fnames, step[free]), corr_list, at_bound, noise,
                    int(res.nfev), {unknowns[k].name: unknowns[k].prior[1] for k in with_prior})
