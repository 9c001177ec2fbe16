"""Whether the gap holds an effect: held-out likelihood tests with a stated false-alarm rate.

The noise model: the weighted relative residual of the baseline at sample i
is ``w_i (s eps_i + e_i eta_i)`` with

* ``s`` the bench noise, white (estimated from the data: second differences
  along each pass, :func:`~.fitting.noise_level`);
* ``e_i`` the baseline's own estimated error at the sample (the budget:
  interpolation between BEM anchors, BEM discretisation), *smooth*: ``eta``
  is a Gaussian process along each pass, unit variance, squared-exponential
  correlation over :data:`MODEL_ERROR_CORRELATION` of the pass, independent
  between receivers;
* ``w_i = s / sqrt(s^2 + e_i^2)`` the fit's weights, so that the weighted
  residual has variance ``s^2``;
* the residuals measured in units of the *estimated* s, itself uncertain
  (:data:`NOISE_ESTIMATE_EFFICIENCY`).

Two statistics are compared with their distributions under that model,
drawn by simulation (:func:`null_draws`):

* **detection**: ``D = max over candidates (SSE_none - SSE_c) / s^2``, the
  best held-out improvement (the candidates refitted on the training folds,
  scored on the held-out ones). Its null distribution is that of the same
  maximum with every candidate linearised (its sensitivity columns at the
  fit) and the object scanned over a grid of places (its first-order dipole
  response at each, one strength), so that the many places an object could
  be are paid for (the look-elsewhere effect). An effect is *detected* when
  D exceeds the null's ``1 - alpha`` quantile: ``alpha`` is the false-alarm
  rate of a noise-only log under the noise model.
* **goodness of fit**: ``T = SSE / s^2`` of a held-out residual (the
  baseline's, or after the chosen effects) against its null distribution
  (about ``N``, wider where the model error is smooth). ``T`` above the
  ``1 - alpha`` quantile: something is left that the noise model does not
  hold.

Every p-value is a Monte-Carlo estimate, ``(1 + #{null >= observed}) / (1 +
draws)``: its resolution is ``1 / draws``.

Example
-------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> P, m = 60, 2
>>> folds = [np.arange(0, 30), np.arange(30, 60)]
>>> J = {"slope": np.tile(np.linspace(-1, 1, P)[:, None], (1, m)).reshape(-1, 1)}
>>> null = null_draws(J, folds, P, m, np.zeros((P, m)), [np.arange(P)], rng=rng, draws=400)
>>> 0.0 < float(np.quantile(null["max_improvement"], 0.99)) < 20.0
True
"""
from __future__ import annotations

import numpy as np

__all__ = ["ALPHA", "MODEL_ERROR_CORRELATION", "null_draws", "smooth_field", "heldout_improvement",
           "p_value", "detection_test", "diagnose_detection"]

#: false-alarm rate of the detection and goodness-of-fit tests
ALPHA = 0.01

#: correlation length of the baseline's error along a pass, as a fraction of the pass's samples (the anchors'
#: spacing, about a tenth of a pass)
MODEL_ERROR_CORRELATION = 0.1

#: degrees of freedom of the noise estimate per residual: s^2 is the mean square of the second differences
#: (:func:`~.fitting.noise_level`), whose neighbours are correlated (-2/3 at lag 1, 1/6 at lag 2), so that their
#: squares carry 1 / (1 + 2 (4/9 + 1/36)) of the information of independent ones: about half
NOISE_ESTIMATE_EFFICIENCY = 0.5

#: Monte-Carlo draws of the null distributions
DRAWS = 400


def smooth_field(rng, passes: list, m: int, draws: int) -> np.ndarray:
    """(draws, P, m) unit-variance Gaussian process along each pass (squared-exponential in the sample index)."""
    P = int(sum(len(p) for p in passes))
    out = np.zeros((draws, P, m))
    for idx in passes:
        idx = np.asarray(idx)
        n = len(idx)
        ell = max(1.0, MODEL_ERROR_CORRELATION * n)
        d = np.arange(n)[:, None] - np.arange(n)[None, :]
        C = np.exp(-0.5 * (d / ell) ** 2) + 1e-9 * np.eye(n)
        w, V = np.linalg.eigh(C)
        L = V * np.sqrt(np.clip(w, 0, None))[None, :]
        out[:, idx, :] = np.einsum("ij,djm->dim", L, rng.standard_normal((draws, n, m)))
    return out


def heldout_improvement(z: np.ndarray, J: np.ndarray, folds: list, P: int, m: int) -> np.ndarray:
    """(draws, C) held-out improvement sum_held (z^2 - (z - J theta_train)^2) of each column set.

    ``z`` (draws, P m); ``J`` (P m, k) one candidate's columns (k >= 1), or (C, P m) one column per
    alternative (then each column is its own one-parameter candidate and C > 1 is returned).
    """
    rows = np.arange(P * m).reshape(P, m)
    if J.ndim == 2 and J.shape[0] == P * m:   # one candidate, k columns
        total = np.zeros(len(z))
        for held in folds:
            tr = np.setdiff1d(np.arange(P), held)
            rt, rh = rows[tr].ravel(), rows[held].ravel()
            A = J[rt]
            theta = np.linalg.lstsq(A, z[:, rt].T, rcond=1e-10)[0]  # (k, draws)
            pred = (J[rh] @ theta).T
            total += np.sum(z[:, rh] ** 2 - (z[:, rh] - pred) ** 2, axis=1)
        return total[:, None]
    V = np.asarray(J)   # (C, P m): one-column candidates
    total = np.zeros((len(z), len(V)))
    for held in folds:
        tr = np.setdiff1d(np.arange(P), held)
        rt, rh = rows[tr].ravel(), rows[held].ravel()
        vv = np.einsum("cn,cn->c", V[:, rt], V[:, rt])
        theta = (z[:, rt] @ V[:, rt].T) / np.where(vv > 0, vv, np.inf)[None, :]   # (draws, C)
        zv = z[:, rh] @ V[:, rh].T
        v2 = np.einsum("cn,cn->c", V[:, rh], V[:, rh])
        total += 2 * theta * zv - theta**2 * v2[None, :]
    return total


def null_draws(designs: dict, folds: list, P: int, m: int, model_error_ratio: np.ndarray, passes: list,
               rng=None, draws: int = DRAWS, local_folds: list | None = None, local: dict | None = None) -> dict:
    """Draws of the null statistics (in units of s^2).

    ``designs``: name -> weighted sensitivity columns (P m, k) of a candidate (scored on ``folds``), or
    (columns, the candidate's own folds);
    ``local``: name -> (C, P m) one-column alternatives scored on ``local_folds`` (the object's places);
    ``model_error_ratio`` (P, m): e_i / s. Returns ``{"max_improvement": (draws,), "sse": (draws,),
    "by_candidate": {name: (draws,)}}``.
    """
    rng = np.random.default_rng(rng)
    ratio = np.asarray(model_error_ratio, float)
    w = 1.0 / np.sqrt(1.0 + ratio**2)
    z = w[None] * (rng.standard_normal((draws, P, m)) + ratio[None] * smooth_field(rng, passes, m, draws))
    # s is estimated from the same data: each draw is measured in units of an estimate of s, whose relative
    # variance is about 1 / nu with nu = NOISE_ESTIMATE_EFFICIENCY * (number of residuals)
    nu = max(1.0, NOISE_ESTIMATE_EFFICIENCY * P * m)
    z = z.reshape(draws, P * m) * np.sqrt(nu / rng.chisquare(nu, draws))[:, None]
    by = {}
    for name, J in designs.items():
        J, own_folds = J if isinstance(J, tuple) else (J, folds)
        J = np.asarray(J, float)
        J = J[:, np.linalg.norm(J, axis=0) > 0]
        if J.shape[1]:
            by[name] = heldout_improvement(z, J, own_folds, P, m)[:, 0]
    for name, V in (local or {}).items():
        if len(V):
            by[name] = heldout_improvement(z, np.asarray(V, float), local_folds or folds, P, m).max(axis=1)
    best = np.max(np.column_stack(list(by.values())), axis=1) if by else np.zeros(draws)
    return {"max_improvement": best, "sse": np.sum(z**2, axis=1), "by_candidate": by}


def p_value(observed: float, null: np.ndarray) -> float:
    """Monte-Carlo p-value ``(1 + #{null >= observed}) / (1 + draws)``.

    >>> p_value(3.0, np.array([1.0, 2.0, 4.0]))
    0.5
    """
    null = np.asarray(null, float)
    return float((1 + np.sum(null >= observed)) / (1 + null.size))


def detection_test(improvement: float, sse_before: float, null: dict, alpha: float = ALPHA) -> dict:
    """The two tests of the module doc on observed statistics (units of s^2) against ``null``."""
    p_det = p_value(improvement, null["max_improvement"])
    p_gof = p_value(sse_before, null["sse"])
    return {
        "alpha": alpha,
        "improvement": float(improvement),
        "improvement_threshold": float(np.quantile(null["max_improvement"], 1 - alpha)),
        "p_detection": p_det,
        "detected": bool(p_det < alpha),
        "sse_before": float(sse_before),
        "sse_threshold": float(np.quantile(null["sse"], 1 - alpha)),
        "p_fit_before": p_gof,
        "draws": int(len(null["sse"])),
    }


def diagnose_detection(problem, ranking: list, folds: list, noise: float, model_error: np.ndarray | None = None,
                       alpha: float = ALPHA, draws: int = DRAWS, seed: int = 0) -> dict:
    """The tests of the module doc for a ranked diagnosis problem.

    ``ranking``: the candidates alone (:func:`~.select.rank_candidates`), ``none`` among them;
    ``model_error`` (P, m): the baseline's estimated relative error at each sample (None: zero). The draws
    are seeded: the same log gets the same verdict.
    """
    from electrosense.validation.diagnosis.fitting import dipole_responses, segment_folds

    obs = problem.obs
    P, m = obs.n_poses, obs.n_receivers
    ratio = np.zeros((P, m)) if model_error is None else np.asarray(model_error, float) / noise
    weighted = lambda c: c.heldout * problem.weight  # noqa: E731
    base = next(c for c in ranking if c.name == "none")
    sse0 = float(np.nansum(weighted(base) ** 2) / noise**2)
    designs, local, observed = {}, {}, {}
    for c in ranking:
        if c.name == "none":
            continue
        observed[c.name] = sse0 - float(np.nansum(weighted(c) ** 2) / noise**2)
        if c.name == "unmodelled_object":
            _, v = dipole_responses(problem, np.arange(P))
            local[c.name] = (v * problem.weight[:, None, :]).transpose(1, 0, 2).reshape(v.shape[1], P * m)
        else:
            designs[c.name] = (c.fit.jac, c.folds or folds)   # held out as the candidate was
    null = null_draws(designs, folds, P, m, ratio, obs.pass_indices(), rng=seed, draws=draws,
                      local_folds=segment_folds(obs), local=local)
    best = max(observed, key=observed.get) if observed else None
    out = detection_test(observed.get(best, 0.0), sse0, null, alpha)
    out.update({
        "noise": float(noise), "null_sse": null["sse"], "best": best,
        "improvement_by_candidate": observed,
        "p_by_candidate": {k: p_value(v, null["max_improvement"]) for k, v in observed.items()},
        "noise_model": "weighted residual w (s eps + e eta): eps white, eta a unit Gaussian process along each pass "
                       f"(correlation {MODEL_ERROR_CORRELATION:.0%} of the pass), e the baseline's estimated error, "
                       "w = s / sqrt(s^2 + e^2); s from second differences along the passes",
    })
    return out
