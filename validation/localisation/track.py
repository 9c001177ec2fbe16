"""The robot's pose from its currents: per-sample maximum likelihood, tracked, and its Cramer-Rao bound.

The measurement model is the one the bench has: each receiver current with
independent Gaussian noise of relative spread ``noise_rel`` (the paper's bench:
0.05 %). A model (a tank map, or the PSM) gives the currents and their
derivatives by (x, y, heading) at any pose of the sensor's depth.

**Why per-sample maximum likelihood, tracked** (and not a Kalman filter or a
batch fit with a motion model): a robot's motion model is not in the log, and
any prior on it would be ours, not the robot's; with three or more receivers
the currents of one sample fix (x, y, heading) on their own, so each sample is
fitted alone (Levenberg-Marquardt on the whitened residuals) and its error is
what the currents and the model make it. The maximum-likelihood estimate is
efficient at small noise: its spread approaches the Cramer-Rao bound of that
sample, (J^T S^-1 J)^-1 with J the model's Jacobian and S the noise's
covariance, so the bound is a fair yardstick for the estimate, and a model
error shows as the excess over it. Each sample starts from the previous
sample's estimate (the first from the logged first pose): the currents alone
cannot tell apart the poses that a tank's mirror planes exchange (a box has
four with the same currents), and tracking keeps the one the robot is in.

Example
-------
>>> import numpy as np
>>> def toy(q):   # currents that depend on (x, y, heading) smoothly, with their Jacobian
...     q = np.atleast_2d(q)
...     I = np.stack([1 + q[:, 0], 1 + q[:, 1], 1 + 0.1 * q[:, 2] + q[:, 0] * q[:, 1]], axis=1)
...     J = np.zeros((len(q), 3, 3)); J[:, 0, 0] = J[:, 1, 1] = 1; J[:, 2, 2] = 0.1
...     J[:, 2, 0], J[:, 2, 1] = q[:, 1], q[:, 0]
...     return I, J
>>> truth = np.array([[0.01, 0.02, 0.1], [0.015, 0.02, 0.12]])
>>> t = track(toy, toy(truth)[0], truth[0])
>>> bool(np.abs(t.poses - truth).max() < 1e-9)
True
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Track", "track", "cramer_rao", "map_currents", "psm_currents", "heading_error",
           "emitter_and_receivers"]


@dataclass
class Track:
    """Estimated (x, y, heading) of every sample, and what the fit says of each."""

    poses: np.ndarray  # (P, 3) x_m, y_m, yaw_rad; NaN where no estimate
    converged: np.ndarray  # (P,) bool
    iterations: np.ndarray  # (P,) int
    chi2: np.ndarray  # (P,) whitened residual sum of squares at the estimate


def heading_error(a, b) -> np.ndarray:
    """a - b wrapped into [-pi, pi)."""
    return (np.asarray(a) - np.asarray(b) + np.pi) % (2 * np.pi) - np.pi


def _refine(model, q, target, w, max_iter, max_step, tol):
    """Levenberg-Marquardt from ``q`` on the whitened residual w (I(q) - target); (q, cost, converged, iterations)
    or None where the model does not cover ``q``."""
    res = model(q[None])
    if res is None:
        return None
    I, J = res[0][0], res[1][0]
    r = w * (I - target)
    cost = float(r @ r)
    lam = 1e-3
    converged, it = False, 0
    while it < max_iter:
        it += 1
        A = w[:, None] * J
        H, g = A.T @ A, A.T @ r
        D = np.diag(np.maximum(np.diag(H), 1e-30))
        accepted = False
        step = np.zeros(3)
        for _ in range(12):
            try:
                step = -np.linalg.solve(H + lam * D, g)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            step *= min(1.0, float(np.min(max_step / np.maximum(np.abs(step), 1e-300))))
            res = model((q + step)[None])
            if res is not None:
                r_new = w * (res[0][0] - target)
                c_new = float(r_new @ r_new)
                if c_new <= cost:
                    q, I, J, r, cost = q + step, res[0][0], res[1][0], r_new, c_new
                    lam = max(lam / 10, 1e-9)
                    accepted = True
                    break
            lam *= 10
        converged = float(step @ H @ step) < tol**2
        if not accepted or converged:
            break
    return q, cost, converged, it


def track(model, currents: np.ndarray, start, noise_rel: float = 5e-4, max_iter: int = 30,
          max_step=(0.01, 0.01, 0.1), tol: float = 1e-6) -> Track:
    """(x, y, heading) of each sample from its receiver currents (module doc).

    Parameters
    ----------
    model : callable
        ``q (k, 3) -> (I (k, m), dI/dq (k, m, 3))``, or ``None`` where a pose is outside what the model covers.
    currents : (P, m)
        Measured receiver currents, in the model's units (per volt of the emitter).
    start : (3,)
        The pose the first sample starts from.
    noise_rel : float or (P, m) array
        Relative noise of a current (1 sigma), one for all or one per current (the noise and a model's own
        error in quadrature): it weights the receivers, not the answer.
    max_step : (3,)
        Largest change of x, y (m) and heading (rad) in one iteration.
    tol : float
        Converged when a step is this small in units of its own uncertainty (step^T H step < tol^2, H the
        Fisher information): far below what the noise lets the currents tell.
    """
    currents = np.asarray(currents, float)
    P = len(currents)
    out = np.full((P, 3), np.nan)
    converged = np.zeros(P, bool)
    iterations = np.zeros(P, int)
    chi2 = np.full(P, np.nan)
    q = np.asarray(start, float).copy()
    max_step = np.asarray(max_step, float)
    spread = np.broadcast_to(np.asarray(noise_rel, float), currents.shape)
    for t in range(P):
        w = 1.0 / (spread[t] * np.abs(currents[t]))
        found = _refine(model, q.copy(), currents[t], w, max_iter, max_step, tol)
        if found is None:   # the last estimate is outside what the model covers: no estimate for this sample
            continue
        q, chi2[t], converged[t], iterations[t] = found
        out[t] = q
    return Track(out, converged, iterations, chi2)


def cramer_rao(jacobian: np.ndarray, currents: np.ndarray, noise_rel: float) -> np.ndarray:
    """(P, 3, 3) Cramer-Rao covariance of (x, y, heading) from one sample: (J^T S^-1 J)^-1, S = diag((noise I)^2).

    >>> J = np.eye(3)[None]; I = np.ones((1, 3))
    >>> cramer_rao(J, I, 0.01)[0].diagonal().tolist()
    [0.0001, 0.0001, 0.0001]
    """
    w = 1.0 / (noise_rel * np.abs(np.asarray(currents, float)))
    A = w[..., None] * np.asarray(jacobian, float)
    fisher = np.einsum("pmi,pmj->pij", A, A)
    return np.linalg.pinv(fisher, hermitian=True)


def emitter_and_receivers(sensor) -> tuple[int, list[int]]:
    """0-based index of the emitter and of the receivers (every other electrode), in electrode order."""
    e = sensor.emitter - 1
    return e, [k for k in range(sensor.n_electrodes) if k != e]


def map_currents(tank_map, z_m: float, sigma_S_per_m: float):
    """A :func:`track` model from a :class:`~electrosense.validation.simulation.tank_map.TankMap` at depth ``z_m``:
    receiver currents per volt (A) and their Jacobian; None outside the map."""
    e, rec = emitter_and_receivers(tank_map.sensor)

    def model(q):
        q = np.atleast_2d(q)
        poses = np.c_[q[:, :2], np.full(len(q), z_m), q[:, 2]]
        if not tank_map.covers(poses)[0].all():
            return None
        K, dK = tank_map.conductance(poses, sigma_S_per_m, jacobian=True)
        return -K[:, rec, e], -np.moveaxis(dK[:, :, rec, e], 1, 2)

    return model


def psm_currents(psm, sensor, tank, z_m: float, sigma_S_per_m: float, objects=()):
    """A :func:`track` model from the PSM (complete images): receiver currents per volt and their analytic
    Jacobian; NaN rows where the sensor is not wholly in the water (the PSM's images are a box's and go on beyond
    its walls: a track that misfits could leave the tank), None where every pose is out or the PSM refuses one
    (a sphere through a wall)."""
    from electrosense.psm import conductance, receiver_current_jacobian
    from electrosense.validation.simulation.tank_map import sensor_wall_gap_m

    e, rec = emitter_and_receivers(sensor)

    def model(q):
        q = np.atleast_2d(q)
        poses = np.c_[q[:, :2], np.full(len(q), z_m), q[:, 2]]
        inside = np.ones(len(q), bool) if tank is None else sensor_wall_gap_m(sensor, tank, poses, objects) > 0
        if not inside.any():
            return None
        if not inside.all():   # one call for the poses in the water (not one per pose: a line search's trials)
            res = model(q[inside])
            if res is None:
                return None
            I, J = np.full((len(q), len(rec)), np.nan), np.full((len(q), len(rec), 3), np.nan)
            I[inside], J[inside] = res
            return I, J
        try:
            K = conductance(psm, poses, sigma_S_per_m, tank=tank, objects=tuple(objects), sensor=sensor).K_S
            J = receiver_current_jacobian(psm, poses, sigma_S_per_m, tank=tank, objects=tuple(objects), sensor=sensor)
        except ValueError:
            return None
        return -K[:, rec, e], J

    return model
