"""A measurement system's common-mode error on four-electrode measurements: a diagnosis candidate for transfer logs.

A differential amplifier of finite common-mode rejection reading the pair ``(p, q)`` also reads a fraction
``c`` of their common-mode voltage ``V_cm = (V_p + V_q) / 2 - V_ref``, with ``V_ref`` the potential of the
instrument's ground (its ground electrode in the water where the scene has one). With a phase shift in the
amplifier ``c = c' + i c''`` is complex, and an instrument that demodulates a magnitude reads

    |Z_meas| = g |Z + c V_cm| = g sqrt((Z + c' V_cm)^2 + (c'' V_cm)^2)

(``Z`` the signed transfer impedance, ``V_cm`` per ampere, ``g`` the system's gain, one per measurement
channel where asked). It makes no error where ``V_cm`` vanishes: for adjacent drives on a symmetric ring, on
the drive's plane of antisymmetry, in the middle of the far side. The quadrature part ``c''`` errs most,
relative to ``Z``, where ``|V_cm / Z|`` is largest (on a 16-electrode pail 2.2 at ring offsets 4-5 and 11-12,
0.98 at 7 and 9, 0.04 at 8), alike on both sides (mirror-symmetric by ring offset); the in-phase part ``c'``
errs with opposite signs on the two sides.

The fit is nonlinear in ``c''`` (it enters squared), so it is its own least-squares problem
(:func:`scipy.optimize.least_squares`, relative residuals, each fold predicted by the fit on the others, as
the linear candidates are scored); the parameters' standard errors come from the Jacobian at the fit and the
residuals' own scatter. ``|c''|`` is determined, its sign is not (``c''`` and ``-c''`` read the same).
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from electrosense.bem.protocol import node_potentials_V

__all__ = ["common_mode_rows", "fit_common_mode", "instrument_reference"]


def instrument_reference(n_electrodes: int, ring, floating=()) -> list[int]:
    """The electrodes (1-based) whose mean potential is the instrument's ground.

    The one electrode that is neither on the measured ring nor floating (a
    ground electrode in the water) where there is exactly one; else the
    ring's mean potential.

    >>> instrument_reference(18, range(1, 17), floating=[17]), instrument_reference(16, range(1, 17))
    ([18], [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16])
    """
    ring = [int(e) for e in ring]
    off = [e for e in range(1, n_electrodes + 1) if e not in set(ring) | {int(f) for f in floating}]
    return off if len(off) == 1 else ring


def common_mode_rows(K_S, drive, measure, reference) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Signed transfer impedance ``Z``, common-mode voltage ``V_cm`` and half the drive pair's voltage of each row
    (all ohm: per ampere).

    ``drive``, ``measure``: (R, 2) 1-based pairs (current from ``drive[:, 0]`` to
    ``drive[:, 1]``; ``Z = V_p - V_q``); ``reference``: electrodes whose mean
    potential is the ground (:func:`instrument_reference`).

    >>> K = np.array([[2.0, -1, -1], [-1, 2, -1], [-1, -1, 2]])     # three electrodes, 1 S between each two
    >>> Z, Vcm, half_drive = common_mode_rows(K, np.array([[1, 2]]), np.array([[1, 3]]), [3])
    >>> Z.round(4).tolist(), Vcm.round(4).tolist(), half_drive.round(4).tolist()
    ([0.3333], [0.1667], [0.3333])
    """
    pairs, inv = np.unique(np.asarray(drive), axis=0, return_inverse=True)
    V = node_potentials_V(K_S, pairs)[inv.ravel()]                        # (R, n) per ampere
    V = V - V[:, np.asarray(reference) - 1].mean(axis=1, keepdims=True)
    rows = np.arange(len(V))
    p, q = np.asarray(measure)[:, 0] - 1, np.asarray(measure)[:, 1] - 1
    a, b = np.asarray(drive)[:, 0] - 1, np.asarray(drive)[:, 1] - 1
    return V[rows, p] - V[rows, q], 0.5 * (V[rows, p] + V[rows, q]), 0.5 * (V[rows, a] - V[rows, b])


def _model(theta, Z, X, channel):
    k = X.shape[1]
    g = theta[:-2 * k][channel]
    return g * np.hypot(Z + X @ theta[-2 * k:-k], X @ theta[-k:])


def _fit(Zd, Z, X, channel, n_gains):
    def residual(theta):
        return _model(theta, Z, X, channel) / Zd - 1

    k = X.shape[1]
    g0 = np.full(n_gains, np.median(Zd / np.abs(Z)))
    scale = np.median(np.abs(Z)) / np.maximum(np.median(np.abs(X), axis=0), 1e-300)
    best = None
    for c2 in (1e-3, 1e-2, 1e-1):   # c'' = 0 is a saddle (it enters squared): start off it, keep the best
        r = least_squares(residual, np.r_[g0, np.zeros(k), c2 * scale], method="lm", x_scale="jac")
        if best is None or r.cost < best.cost:
            best = r
    return best


def fit_common_mode(Zd, Z, Vcm, folds, channel=None) -> tuple[dict, np.ndarray, dict]:
    """Fit ``|Z_meas| = g |Z + c V_cm|`` and score it as the linear candidates are scored.

    Parameters
    ----------
    Zd : (R,) measured magnitudes; ``Z``, ``Vcm`` : (R,) from :func:`common_mode_rows`.
    folds : (R,) fold of each row (each fold predicted by the fit on the others; fold 1 is "held out").
    channel : (R,) measurement channel of each row for one gain per channel, or None for one gain.

    Returns
    -------
    ``(scores, residuals, parameters)``: ``heldout_rms_rel``, ``twofold_rms_rel`` and ``n_parameters``; the
    held-out relative residuals (R,); the fit holding fold 1 out: ``c_in_phase`` and ``c_quadrature`` (``|c''|``)
    with standard errors, and ``gains_rel`` (per channel) where fitted.

    >>> rng = np.random.default_rng(0)
    >>> Z, Vcm = rng.uniform(0.1, 1, 200) * rng.choice([-1, 1], 200), rng.normal(0, 2, 200)
    >>> Zd = 3.0 * np.hypot(Z + 0.01 * Vcm, 0.05 * Vcm) * (1 + 1e-4 * rng.standard_normal(200))
    >>> sc, res, p = fit_common_mode(Zd, Z, Vcm, np.arange(200) % 2)
    >>> round(p["c_in_phase"], 3), round(p["c_quadrature"], 3), sc["heldout_rms_rel"] < 3e-4
    (0.01, 0.05, True)
    """
    Zd, Z, folds = (np.asarray(a, float) for a in (Zd, Z, folds))
    X = np.asarray(Vcm, float).reshape(len(Zd), -1)
    if channel is None:
        channel = np.zeros(len(Zd), int)
    channel = np.unique(np.asarray(channel), return_inverse=True)[1].ravel()
    n_gains = int(channel.max()) + 1
    res = np.zeros(len(Zd))
    params = {}
    for f in np.unique(folds):
        tr = folds != f
        fit = _fit(Zd[tr], Z[tr], X[tr], channel[tr], n_gains)
        res[~tr] = _model(fit.x, Z[~tr], X[~tr], channel[~tr]) / Zd[~tr] - 1
        if f == 1 or len(params) == 0:
            params = _parameters(fit, n_gains, X.shape[1])
    rms = float(np.sqrt(np.mean(res[folds == 1] ** 2))) if np.any(folds == 1) else float("nan")
    return ({"heldout_rms_rel": rms, "twofold_rms_rel": float(np.sqrt(np.mean(res ** 2))),
             "n_parameters": n_gains + 2 * X.shape[1]}, res, params)


def _parameters(fit, n_gains, k) -> dict:
    """The fitted coefficients with standard errors (Jacobian at the fit, residual scatter as the noise)."""
    J, r = fit.jac, fit.fun
    dof = max(len(r) - len(fit.x), 1)
    try:
        se = np.sqrt(np.clip(np.diag(np.linalg.pinv(J.T @ J)) * float(r @ r) / dof, 0, None))
    except np.linalg.LinAlgError:
        se = np.full(len(fit.x), np.nan)
    one = (lambda a: float(a[0])) if k == 1 else (lambda a: np.asarray(a, float).tolist())
    out = {"c_in_phase": one(fit.x[-2 * k:-k]), "c_in_phase_se": one(se[-2 * k:-k]),
           "c_quadrature": one(np.abs(fit.x[-k:])), "c_quadrature_se": one(se[-k:])}
    if n_gains > 1:
        g = fit.x[:-2 * k]
        out["gains_rel"] = np.round(g / g.mean(), 4).tolist()
    return out
