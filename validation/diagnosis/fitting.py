"""Fitting candidate effects: least squares on part of the data, scored on the rest.

* :func:`noise_level`: the measurement noise (relative), estimated from the
  data alone: the robust spread of second differences of the residual along
  each pass (a smooth gap hardly changes between neighbouring samples; white
  noise does, with variance 6 s^2).
* :func:`make_folds`: held-out sets: whole passes when there are three or
  more, otherwise contiguous segments of every pass (8 blocks in time, fold k
  holds blocks k and k + 4); :func:`folds_determining` keeps whole passes for a
  candidate only where each fold's training passes determine all its
  parameters (:func:`standard_error_ratio`), else segments of every pass.
* :func:`fit`: nonlinear least squares of the relative residual
  (bench - prediction) / |baseline| over the training samples, in scaled
  parameters, with the covariance ``s^2 (J^T J)^-1`` from the Jacobian at the
  optimum.
* :func:`cross_validate`: refit on each training set, predict its held-out
  set; the pooled held-out residual.
* :func:`object_starts`: starting points for the sphere: a scan of a grid of
  places with the first-order (dipole, free-space) response of the sensor.
* :func:`subspace_angle_deg`: the smallest angle between the sensitivity
  columns of two candidates (0 deg: cannot be told apart on these data).

Example
-------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> r = 1e-3 * rng.standard_normal((400, 3))
>>> bool(abs(noise_level(r, [np.arange(400)]) / 1e-3 - 1) < 0.1)  # within 3 standard errors
True
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import subspace_angles
from scipy.optimize import lsq_linear

from electrosense.meshes.pose import sensor_to_tank
from electrosense.meshes.tank import Tank
from electrosense.validation.comparison.metrics import noise_level
from electrosense.validation.diagnosis.effects import Problem, combined_bounds, combined_scales
from electrosense.validation.diagnosis.forward import receiver_currents

__all__ = [
    "FitResult",
    "noise_level",
    "make_folds",
    "folds_determining",
    "standard_error_ratio",
    "segment_folds",
    "predict",
    "scenario",
    "fit",
    "cross_validate",
    "object_starts",
    "dipole_responses",
    "subspace_angle_deg",
]

#: residual given to a parameter set the model refuses (e.g. a sphere through the sensor)
_REFUSED = 1.0


def segment_folds(obs, n_blocks: int = 8) -> list[np.ndarray]:
    """Held-out contiguous time segments of every pass (:func:`make_folds` with any number of passes): the
    folds of a *local* effect (an object beside one pass), which whole held-out passes could never predict.

    Example
    -------
    >>> from types import SimpleNamespace
    >>> obs = SimpleNamespace(pass_indices=lambda: [np.arange(16), np.arange(16, 32), np.arange(32, 48)])
    >>> folds = segment_folds(obs)
    >>> len(folds), folds[0][:4].tolist()
    (4, [0, 1, 8, 9])
    """
    return make_folds(obs, n_blocks=n_blocks, min_passes=np.iinfo(np.int64).max)


#: a fold's training samples must determine every fitted parameter to within this many times the standard error
#: of all the samples (evenly informative passes give sqrt(P / P_train): 1.2 of three passes held out one at a time)
DETERMINED_SE_RATIO = 3.0


def standard_error_ratio(jac: np.ndarray, folds, n_poses: int) -> np.ndarray:
    """(folds, k) standard error of each parameter from a fold's training samples over that from all samples.

    ``jac`` (P m, k): the weighted residual's Jacobian at the fit, rows sample-major. A parameter that only
    the held-out samples see has a ratio far above one (infinite where the training samples do not see it).

    The second parameter is seen by samples 4-7 only: held out, nothing determines it.

    >>> J = np.r_[np.c_[np.ones(4), np.zeros(4)], np.c_[np.ones(4), np.ones(4)]]   # 8 samples, m = 1
    >>> standard_error_ratio(J, [np.arange(2), np.arange(4, 8)], 8).round(2).tolist()
    [[1.41, 1.22], [inf, inf]]
    """
    jac = np.asarray(jac, float)
    k = jac.shape[1]
    m = jac.shape[0] // n_poses
    rows = jac.reshape(n_poses, m, k)

    def se(J):
        F = J.T @ J
        if np.linalg.matrix_rank(F, tol=1e-10 * max(np.trace(F), 1e-300)) < k:
            return np.full(k, np.inf)
        return np.sqrt(np.diag(np.linalg.inv(F)))

    full = se(jac)
    out = []
    for held in folds:
        train = np.setdiff1d(np.arange(n_poses), held)
        fold = se(rows[train].reshape(-1, k))
        # where all the samples do not determine the parameters, no choice of folds does: no reason to change them
        out.append(fold / full if np.all(np.isfinite(full)) else np.ones(k))
    return np.array(out)


def folds_determining(jac: np.ndarray, obs, folds) -> list[np.ndarray]:
    """``folds`` if each fold's training samples determine every parameter (:func:`standard_error_ratio` within
    :data:`DETERMINED_SE_RATIO`), else :func:`segment_folds`.

    Held-out whole passes test whether the effect fitted on some passes predicts another; they cannot where a
    parameter is seen by the held-out pass alone (a tank's width by the one pass near a side wall, a shift
    across the path by the one pass across it): the training fit then moves that parameter to absorb whatever
    else it sees, and the held-out pass pays for a parameter its training set never determined. Held-out
    segments of every pass leave every parameter determined.
    """
    if jac is None or not np.size(jac):
        return folds
    ratio = standard_error_ratio(jac, folds, obs.n_poses)
    return folds if np.all(ratio <= DETERMINED_SE_RATIO) else segment_folds(obs)


def make_folds(obs, n_blocks: int = 8, max_folds: int = 5, min_passes: int = 3) -> list[np.ndarray]:
    """Held-out index sets: whole passes, or contiguous time segments of every pass.

    With at least ``min_passes`` passes, each fold holds out whole passes
    (grouped into at most ``max_folds`` folds). With fewer, each pass is cut
    into ``n_blocks`` contiguous blocks in time and fold k holds out blocks k
    and k + n_blocks/2 of every pass: with two passes that see different
    things (e.g. two lines at different y) holding one out would leave the
    other unable to determine a multi-parameter effect.
    """
    passes = obs.pass_indices()
    if len(passes) >= min_passes:
        k = min(len(passes), max_folds)
        return [np.sort(np.concatenate(passes[i::k])) for i in range(k)]
    k = n_blocks // 2
    folds = [[] for _ in range(k)]
    for order in passes:
        blocks = np.array_split(order, n_blocks)
        for i in range(k):
            folds[i] += [blocks[i], blocks[i + k]]
    return [np.sort(np.concatenate(f)) for f in folds]


def _split(effects, theta):
    out, i = [], 0
    for e in effects:
        out.append(np.asarray(theta[i:i + e.n_params], float))
        i += e.n_params
    return out


def predict(problem: Problem, effects, theta, idx) -> np.ndarray:
    """Receiver currents (p, m) with ``effects`` at physical parameters ``theta`` for samples ``idx``.

    A geometric effect changes the scene at every sample (the effect model is then evaluated once per
    parameter vector for all samples and memoised, whichever subset asks: the training set of a fold and its
    held-out set share it); the others only at ``idx``.
    """
    idx = np.asarray(idx)
    rows = np.arange(problem.obs.n_poses) if any(e.geometric for e in effects) else idx
    I = problem.predict(scenario(problem, effects, theta, rows), idx)
    if problem.secants:   # the BEM's own answer at a fitted scene (:mod:`.bem_secant`)
        for e, part in zip(effects, _split(effects, theta)):
            secant = problem.secants.get(e.label)
            if secant is not None:
                I = I * np.exp(secant.log_change(part / np.asarray(e.scales, float), idx))
    return I


def scenario(problem: Problem, effects, theta, rows):
    """The :class:`Scenario` of the samples ``rows`` with ``effects`` at physical parameters ``theta``, applied in
    the order of the physics (each effect's ``order``)."""
    sc = problem.nominal(rows)
    parts = _split(effects, theta)
    for k in sorted(range(len(effects)), key=lambda j: effects[j].order):
        sc = effects[k].apply(parts[k], sc, problem, rows)
    return sc


def _residual(problem, effects, theta, idx) -> np.ndarray:
    """Weighted relative residual (p * m,) of ``effects`` at ``theta`` for the samples ``idx``."""
    try:
        I = predict(problem, effects, theta, idx)
    except (ValueError, np.linalg.LinAlgError, FloatingPointError):
        return np.full(len(idx) * problem.obs.n_receivers, _REFUSED)
    r = (problem.relative_residual(I, idx) * problem.weight[idx]).ravel()
    if not np.all(np.isfinite(r)):
        return np.full(r.size, _REFUSED)
    return r


@dataclass
class FitResult:
    """A fitted combination of effects."""

    effects: tuple
    theta: np.ndarray
    cov: np.ndarray
    train_rms: float
    n_train: int
    jac: np.ndarray = field(repr=False)  # d residual / d theta (physical units), (N, k)
    success: bool = True
    message: str = ""

    @property
    def n_params(self) -> int:
        return int(sum(e.n_params for e in self.effects))

    @property
    def names(self) -> list[str]:
        return [e.name for e in self.effects]

    def params(self) -> dict:
        """``{effect name: {param: value}}`` (physical units)."""
        out, i = {}, 0
        for e in self.effects:
            out[e.name] = {p: float(self.theta[i + j]) for j, p in enumerate(e.param_names)}
            i += e.n_params
        return out

    def uncertainty(self) -> dict:
        """``{effect name: {param: 1-sigma}}`` from the Jacobian at the optimum."""
        sd = np.sqrt(np.clip(np.diag(self.cov), 0, None)) if self.cov.size else np.zeros(0)
        out, i = {}, 0
        for e in self.effects:
            out[e.name] = {p: float(sd[i + j]) for j, p in enumerate(e.param_names)}
            i += e.n_params
        return out


def _jacobian(fun, u, f, lower, upper, h: float = 1e-3) -> np.ndarray:
    """Forward differences of ``fun`` at ``u`` (scaled units), stepping inwards at a bound."""
    J = np.empty((f.size, u.size))
    for j in range(u.size):
        step = h * max(1.0, abs(u[j]))
        if u[j] + step > upper[j]:
            step = -step
        v = u.copy()
        v[j] += step
        J[:, j] = (fun(v) - f) / step
    return J


def _bounded_step(J, f, lower, upper, u, lam: float) -> np.ndarray:
    """Levenberg-Marquardt step: min |f + J du|^2 + lam |du|^2 with u + du within the bounds."""
    k = u.size
    A = np.vstack([J, np.sqrt(lam) * np.eye(k)])
    b = np.concatenate([-f, np.zeros(k)])
    lo, hi = lower - u, upper - u
    hi = np.maximum(hi, lo + 1e-12)
    return lsq_linear(A, b, bounds=(lo, hi), method="bvls").x


def fit(problem: Problem, effects, idx, theta0=None, noise: float | None = None, max_iter: int = 12) -> FitResult:
    """Least-squares fit of ``effects`` (a list of :class:`Effect`) on the samples ``idx``.

    Levenberg-Marquardt within the bounds, in units of each effect's
    ``scales``, with a forward-difference Jacobian (k + 1 model evaluations
    per iteration, none when a step is refused). With no parameter (``none``)
    the residual of the baseline is returned.
    """
    effects = tuple(effects)
    idx = np.asarray(idx)
    k = int(sum(e.n_params for e in effects))
    if k == 0:
        r = _residual(problem, effects, np.zeros(0), idx)
        return FitResult(effects, np.zeros(0), np.zeros((0, 0)), float(np.sqrt(np.mean(r**2))), r.size, np.zeros((r.size, 0)))
    scales = combined_scales(effects)
    lower, upper = (b / scales for b in combined_bounds(effects))
    u = np.zeros(k) if theta0 is None else np.asarray(theta0, float) / scales
    u = np.clip(u, lower, upper)

    def fun(v):
        return _residual(problem, effects, v * scales, idx)

    f = fun(u)
    cost = float(f @ f)
    J = _jacobian(fun, u, f, lower, upper)
    lam = 1e-3 * float(np.mean(np.sum(J**2, axis=0))) + 1e-30
    message = "max iterations"
    for _ in range(max_iter):
        du = _bounded_step(J, f, lower, upper, u, lam)
        f_new = fun(u + du)
        cost_new = float(f_new @ f_new)
        if cost_new < cost:
            u, f = u + du, f_new
            converged = cost - cost_new < 1e-6 * cost or np.max(np.abs(du)) < 1e-4
            cost = cost_new
            lam = max(lam / 5, 1e-30)
            J = _jacobian(fun, u, f, lower, upper)
            if converged:
                message = "converged"
                break
        else:
            lam *= 8
            if lam > 1e12 * (1 + float(np.max(np.sum(J**2, axis=0)))):
                message = "no further decrease"
                break
    theta = u * scales
    Jp = -J / scales[None, :]  # d prediction-residual / d theta, physical units (sign: d model / d theta)
    dof = max(f.size - k, 1)
    s2 = cost / dof
    if noise is not None:
        s2 = max(s2, noise**2)
    cov = s2 * np.linalg.pinv(Jp.T @ Jp, rcond=1e-12, hermitian=True)
    return FitResult(effects, theta, cov, float(np.sqrt(cost / f.size)), f.size, Jp, True, message)


def cross_validate(problem: Problem, effects, folds, full: FitResult | None = None, noise=None):
    """Pooled held-out residual (P, m), weighted: each fold predicted after a refit on the other samples.

    The refit is the Gauss-Newton step from the full-data optimum ``full``
    (its Jacobian, rows of the training samples), within the bounds, halved
    until it does not worsen the training fit; the held-out residual is then
    evaluated exactly. Returns ``(residual, thetas)``.
    """
    effects = tuple(effects)
    P, m = problem.obs.n_poses, problem.obs.n_receivers
    out = np.full((P, m), np.nan)
    everything = np.arange(P)
    if full is None:
        full = fit(problem, effects, everything, noise=noise)
    k = full.n_params
    if k == 0:
        r = _residual(problem, effects, np.zeros(0), everything).reshape(P, m)
        return r, [np.zeros(0) for _ in folds]
    scales = combined_scales(effects)
    lower = np.concatenate([np.asarray(e.lower, float) for e in effects]) / scales
    upper = np.concatenate([np.asarray(e.upper, float) for e in effects]) / scales
    u_full = full.theta / scales
    f_full = _residual(problem, effects, full.theta, everything).reshape(P, m)
    J = -(full.jac * scales[None, :]).reshape(P, m, k)  # d residual / d u
    thetas = []
    for held in folds:
        train = np.setdiff1d(everything, held)
        Jt = J[train].reshape(-1, k)
        ft = f_full[train].ravel()
        cost0 = float(ft @ ft)
        du = _bounded_step(Jt, ft, lower, upper, u_full, 1e-6 * float(np.mean(np.sum(Jt**2, axis=0))) + 1e-30)
        # backtrack: the step must not make the training fit worse (nonlinear effects, refused scenes)
        for _ in range(6):
            rt = _residual(problem, effects, (u_full + du) * scales, train)
            if float(rt @ rt) <= cost0:
                break
            du = du / 2
        else:
            du = np.zeros(k)
        theta = (u_full + du) * scales
        r_held = _residual(problem, effects, theta, held)
        for _ in range(6):  # a refit whose scene the held-out poses cannot have (a wall through a pose): step back
            if not np.any(r_held == _REFUSED):
                break
            du = du / 2
            theta = (u_full + du) * scales
            r_held = _residual(problem, effects, theta, held)
        thetas.append(theta)
        out[held] = r_held.reshape(len(held), m)
    return out, thetas


# ------------------------------------------------------------------- object starts
def _object_grid(problem: Problem, n_xy: int = 13, n_z: int = 5) -> np.ndarray:
    obs = problem.obs
    if obs.tank is not None:
        lo, hi = obs.tank.water_bounds_m
        lo, hi = lo + 0.03, hi - 0.03
    else:
        lo = obs.poses[:, :3].min(axis=0) - 0.3
        hi = obs.poses[:, :3].max(axis=0) + 0.3
    axes = [np.linspace(lo[0], hi[0], n_xy), np.linspace(lo[1], hi[1], n_xy), np.linspace(lo[2], hi[2], n_z)]
    g = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    # keep out of the volume the sensor sweeps (with a margin)
    ends = np.array([[0.5 * obs.sensor.length_m, 0, 0], [-0.5 * obs.sensor.length_m, 0, 0]])
    seg = sensor_to_tank(ends, obs.poses[:: max(1, obs.n_poses // 100)])  # (p, 2, 3)
    a, b = seg[:, 0], seg[:, 1]
    ab = b - a
    t = np.clip(np.einsum("gpk,pk->gp", g[:, None, :] - a[None], ab) / np.sum(ab * ab, axis=-1), 0, 1)
    closest = a[None] + t[..., None] * ab[None]
    dist = np.linalg.norm(g[:, None, :] - closest, axis=-1).min(axis=1)
    return g[dist > obs.sensor.radius_m + 0.02]


def dipole_responses(problem: Problem, idx) -> tuple[np.ndarray, np.ndarray]:
    """(grid (G, 3), v (p, G, m)): the first-order relative change of the receiver currents at samples ``idx``
    by a unit dipole (chi b^3 = 1 m^3) at each place of the object grid: from the BEM's field where the place is
    (:mod:`.object_field`) when the problem has it, else the PSM's small-object term with the electrode centres,
    in free space, on the baseline's conductance."""
    obs = problem.obs
    grid = _object_grid(problem)
    if len(grid) == 0:
        return grid, np.zeros((len(idx), 0, obs.n_receivers))
    if problem.object_field is not None and (obs.tank is None or isinstance(obs.tank, Tank)):
        dK = problem.object_field.unit_dipoles(obs.poses[idx], obs.tank, grid)   # (p, G, n, n)
        dI = receiver_currents(dK, obs.emitter) * obs.U_V[idx, None, None]
        return grid, dI / np.abs(problem.I_base[idx])[:, None, :]
    n, e = obs.sensor.n_electrodes, obs.emitter - 1
    rec = [k for k in range(n) if k != e]
    c = sensor_to_tank(obs.sensor.electrode_centres_m, obs.poses[idx])  # (p, n, 3)
    u = c[:, :, None, :] - grid[None, None, :, :]  # (p, n, G, 3)
    ru3 = np.linalg.norm(u, axis=-1) ** 3  # (p, n, G)
    dot = -np.einsum("pagk,pbgk->pgab", u, u)  # (c_a - x).(x - c_b)
    dM = dot / (ru3.transpose(0, 2, 1)[:, :, :, None] * ru3.transpose(0, 2, 1)[:, :, None, :])
    dM = dM / (4 * np.pi * obs.sigma_S_per_m)  # (p, G, n, n) per unit dipole strength
    # P^T dM P with P = receivers' identity and -1 on the emitter row
    A = dM[..., rec, :][..., :, rec] - dM[..., rec, e][..., :, None] - dM[..., e, rec][..., None, :] + dM[..., e, e][..., None, None]
    G = problem.K_base[idx][:, rec][:, :, rec]  # (p, m, m)
    g1 = G.sum(axis=-1)  # G 1
    dI = -np.einsum("pij,pgjk,pk->pgi", G, A, g1) * obs.U_V[idx, None, None]
    return grid, dI / np.abs(problem.I_base[idx])[:, None, :]  # relative, (p, G, m)


def object_starts(problem: Problem, idx, r: np.ndarray, n_best: int = 3) -> list[np.ndarray]:
    """Starting parameters (x, y, z, chi b^3) for the sphere from a grid scan of the residual ``r`` (p, m):
    the places whose unit-dipole response (:func:`dipole_responses`) explains most of it, with their best
    strength."""
    grid, v = dipole_responses(problem, idx)
    if len(grid) == 0:
        return []
    vv = np.einsum("pgi,pgi->g", v, v)
    vr = np.einsum("pgi,pi->g", v, r)
    ok = vv > 0
    gain = np.where(ok, vr**2 / np.where(ok, vv, 1), 0.0)
    best = np.argsort(gain)[::-1][:n_best]
    return [np.array([*grid[b], vr[b] / vv[b]]) for b in best if ok[b] and gain[b] > 0]


# ------------------------------------------------------------------ confusability
def subspace_angle_deg(J_a: np.ndarray, J_b: np.ndarray) -> float:
    """Smallest principal angle (deg) between the column spaces of two sensitivity matrices."""
    if J_a.size == 0 or J_b.size == 0:
        return 90.0
    keep_a = np.linalg.norm(J_a, axis=0) > 0
    keep_b = np.linalg.norm(J_b, axis=0) > 0
    if not keep_a.any() or not keep_b.any():
        return 90.0
    return float(np.degrees(np.min(subspace_angles(J_a[:, keep_a], J_b[:, keep_b]))))
