"""The robot's track from its currents with what a robot knows: it moves along a continuous path at bounded speed.

**Motion model.** The state of each sample is the pose q = (x, y, heading) and its rate v = dq/dt; between samples
``dt`` apart the pose moves at constant velocity while a white-noise acceleration of spectral density
``diag(q_xy, q_xy, q_yaw)`` (m^2/s^3, rad^2/s^3) changes the velocity (the "white-noise acceleration" or nearly
constant velocity model of tracking; Bar-Shalom, Li & Kirubarajan 2001, 6.2.2):

    s_{t+1} = F s_t + w_t,   F = [[1, dt], [0, 1]] per axis,   w_t ~ N(0, q [[dt^3/3, dt^2/2], [dt^2/2, dt]]).

Over a time T the velocity so wanders by sqrt(q T) and the position by sqrt(q T^3 / 3): ``q_xy`` is the square of
the speed change (m/s) a robot makes in one second that is not planned. The prior on the first state of each pass is
diffuse (1 m, 1 m/s, 10 rad, 10 rad/s: a pass is not told where it starts), and each pass of a log is its own chain
(a bench reverses at the end of a pass). In a round tank, whose currents are the same at every rotation about its
axis, the start gives that angle and a bench robot's first velocity (:func:`first_state_prior`).

**Measurement model.** As in :mod:`.track`: each receiver current with independent Gaussian noise of relative spread
``noise_rel``, the model's currents I(q) and their Jacobian dI/dq.

**Why a batch maximum a posteriori over the whole log** (Gauss-Newton on all poses at once, each step solved by a
Kalman filter and Rauch-Tung-Striebel smoother of the linearised problem, i.e. the iterated extended Kalman smoother,
Bell 1994) rather than a filter or per-sample fits: near a wall the currents of one sample fix the distance to the
wall to a millimetre but the position along it hardly at all (the per-sample Cramer-Rao bound reaches metres mid-wall),
so per-sample estimates wander along the wall. The currents near the ends of a pass, where a second wall is near, fix
the along-wall position; the motion model carries that to the middle, both forward and backward in time, which only a
smoother (not a causal filter) can do. Gauss-Newton iterated to convergence makes the estimate the exact maximum of
the posterior, not a linearisation at predicted states (the plain extended Kalman smoother); the linear smoother
solves each step in O(P) and gives the posterior covariance of every pose. The first iterate is an iterated extended
Kalman filter forward pass from the first logged pose (the currents alone cannot tell apart the poses that a tank's
mirror planes exchange: the start picks the robot's one) and its smoother. A loose prior lets a track started
poorly slide along a wall into a false minimum (a mirror image of its far end): the fit is solved first under the
prior made 10^4 and 10^2 times stiffer, each from the last, then under the stated one (continuation).

A per-sample fit (:func:`.track.track`, ``esense localise --per-sample``) uses no motion model; it is what a robot
gets whose motion is unknown, and its bound is the per-sample one, metres along a wall.

**The bound.** The posterior (Bayesian) Cramer-Rao bound of this estimator at a track: the inverse of the Fisher
information of the measurements at the true poses, J^T S^-1 J, plus the information of the motion prior; its diagonal
blocks are the smoothed covariances of the linear smoother with the Jacobians at the true poses
(:func:`posterior_crb`). With the prior switched off it is the per-sample bound of :func:`.track.cramer_rao`. It
averages over the tracks the prior allows: on a straight pass at constant speed, which costs the prior nothing, the
estimator's own error is about half of it; :func:`expected_error` gives that error on the given track (the prior's
bias and the noise through the smoother, linearised), so that an error above it is the model's.

Example
-------
>>> import numpy as np
>>> def toy(q):   # currents that fix x and heading but y only weakly, as along a wall
...     q = np.atleast_2d(q)
...     I = np.stack([1 + q[:, 0], 1 + 1e-3 * q[:, 1], 1 + 0.1 * q[:, 2]], axis=1)
...     J = np.zeros((len(q), 3, 3)); J[:, 0, 0] = 1; J[:, 1, 1] = 1e-3; J[:, 2, 2] = 0.1
...     return I, J
>>> t = np.arange(50) * 0.1
>>> truth = np.c_[0.01 + 0 * t, 0.02 * t, 0 * t]
>>> rng = np.random.default_rng(0)
>>> I = toy(truth)[0] * (1 + 1e-4 * rng.standard_normal((50, 3)))
>>> est = smooth_track(toy, I, t, truth[0], MotionModel(1e-6, 1e-4), noise_rel=1e-4)
>>> crb = posterior_crb(toy(truth)[1], I, t, MotionModel(1e-6, 1e-4), 1e-4)
>>> bool(np.sqrt(np.mean((est.poses[:, 1] - truth[:, 1]) ** 2)) < 3 * np.sqrt(np.mean(crb[:, 1, 1])))
True
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from electrosense.validation.localisation.track import track

__all__ = ["MotionModel", "DEFAULT_MOTION", "SmoothedTrack", "smooth_track", "posterior_crb", "expected_error",
           "rts_smoother", "first_state_prior", "ROTATION_GAUGE_SIGMA_RAD", "ROUND_TANK_FIRST_VELOCITY_SIGMA"]

#: the diffuse prior on the first state of a pass: 1 m, 1 m, 10 rad; 1 m/s, 1 m/s, 10 rad/s (1 sigma)
DIFFUSE_SIGMA = np.array([1.0, 1.0, 10.0, 1.0, 1.0, 10.0])

#: in a round tank the currents are the same at every rotation of the pose about the tank's axis: nothing in them
#: fixes that angle, so the first pose of a log gives it, to this spread (1 sigma, rad; 0.2 mm at 20 cm from the axis)
ROTATION_GAUGE_SIGMA_RAD = 1e-3

#: ... and the first velocity is a bench robot's, 0.1 m/s and 1 rad/s (1 sigma), not the diffuse prior: a rotation
#: about the axis at a steady rate leaves the currents as they are too, and with a diffuse first velocity the first
#: samples' linearisation turned the track that way and out of the tank (a chord of a 0.25 m tank with 0.05 % noise:
#: metres off; with this prior 16 mm at most, its bound 48 mm RMS)
ROUND_TANK_FIRST_VELOCITY_SIGMA = np.array([0.1, 0.1, 1.0])


def first_state_prior(start, round_tank: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(m0 (6,), P0 (6, 6)): the prior on the first state of a pass, started at the pose ``start`` (x, y, yaw).

    Diffuse (:data:`DIFFUSE_SIGMA`): the start only picks among the poses a box's mirror planes exchange. In a
    round tank (``round_tank``) the currents leave a whole circle of poses open, every rotation about the axis;
    the prior then holds the start's angle about the axis, ``atan2(y, x)``, to :data:`ROTATION_GAUGE_SIGMA_RAD`
    (its gradient ``(-y, x, 0) / r^2`` gets that information; at the axis itself, the heading), and leaves the
    distance from the axis and the heading against it to the currents; its first velocity is a bench robot's
    (:data:`ROUND_TANK_FIRST_VELOCITY_SIGMA`).

    >>> m0, P0 = first_state_prior((0.1, 0.0, 0.3), round_tank=True)
    >>> round(float(np.sqrt(P0[1, 1])) * 1e3, 3), round(float(np.sqrt(P0[0, 0])), 3)   # along the circle, radial
    (0.1, 1.0)
    """
    q = np.asarray(start, float)[:3]
    m0 = np.r_[q, np.zeros(3)]
    if not round_tank:
        return m0, np.diag(DIFFUSE_SIGMA**2)
    r2 = q[0] ** 2 + q[1] ** 2
    g = np.r_[-q[1] / r2, q[0] / r2, 0.0, np.zeros(3)] if r2 > 1e-6 else np.r_[0.0, 0.0, 1.0, np.zeros(3)]
    sigma = np.r_[DIFFUSE_SIGMA[:3], ROUND_TANK_FIRST_VELOCITY_SIGMA]
    information = np.diag(sigma**-2.0) + np.outer(g, g) / ROTATION_GAUGE_SIGMA_RAD**2
    P0 = np.linalg.inv(information)
    return m0, 0.5 * (P0 + P0.T)


@dataclass(frozen=True)
class MotionModel:
    """Nearly constant velocity: white-noise acceleration of these spectral densities (module doc).

    ``acceleration_psd_m2_per_s3``: of x and y (the square of the unplanned speed change in one second, (m/s)^2);
    ``turn_psd_rad2_per_s3``: of the heading ((rad/s)^2 of unplanned turn-rate change in one second). The defaults
    are a bench's cartesian robot, which holds its programmed speed to about 1 mm/s and its heading rate to about
    3 mrad/s over a second; a free-swimming robot that changes speed by some cm/s in a second needs about 1e-3
    (the bound then grows where the currents alone see little, see ``esense study tank_map``).
    """

    acceleration_psd_m2_per_s3: float = 1e-6
    turn_psd_rad2_per_s3: float = 1e-5

    def __post_init__(self):
        for name, v in asdict(self).items():
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v!r}")

    @property
    def psd(self) -> np.ndarray:
        q = self.acceleration_psd_m2_per_s3
        return np.array([q, q, self.turn_psd_rad2_per_s3])

    def transition(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(F, Q), 6 x 6, of a step of ``dt`` seconds; the state is (x, y, yaw, vx, vy, yaw rate)."""
        if not dt > 0:
            raise ValueError(f"samples must be in time order with distinct times (a step of {dt} s)")
        F = np.eye(6)
        F[:3, 3:] = dt * np.eye(3)
        c = np.diag(self.psd)
        Q = np.block([[dt**3 / 3 * c, dt**2 / 2 * c], [dt**2 / 2 * c, dt * c]])
        return F, Q

    def cost(self, s: np.ndarray, t_s: np.ndarray) -> float:
        """Sum over steps of d^T Q^-1 d, d = s_{t+1} - F s_t (the prior's part of -2 log posterior)."""
        dt = np.diff(t_s)[:, None]
        dq = s[1:, :3] - s[:-1, :3] - dt * s[:-1, 3:]
        dv = s[1:, 3:] - s[:-1, 3:]
        # Q^-1 of one axis: (1/q) [[12/dt^3, -6/dt^2], [-6/dt^2, 4/dt]]
        c = (12 / dt**3 * dq**2 - 12 / dt**2 * dq * dv + 4 / dt * dv**2) / self.psd[None]
        return float(c.sum())

    def record(self) -> dict:
        return {"name": "nearly constant velocity (white-noise acceleration), each pass its own chain",
                "acceleration_psd_m2_per_s3": self.acceleration_psd_m2_per_s3,
                "turn_psd_rad2_per_s3": self.turn_psd_rad2_per_s3,
                "first_state_prior_sigma": DIFFUSE_SIGMA.tolist(),
                "state": "x_m, y_m, yaw_rad, vx_m_per_s, vy_m_per_s, yaw_rate_rad_per_s"}


#: the default motion prior (a bench's cartesian robot)
DEFAULT_MOTION = MotionModel()


def rts_smoother(H: list, y: list, t_s: np.ndarray, motion: MotionModel, m0: np.ndarray, P0: np.ndarray):
    """The linear Kalman filter and Rauch-Tung-Striebel smoother of one pass.

    ``H[t]`` (m_t, 3) and ``y[t]`` (m_t,): whitened measurements y = H q + e, e ~ N(0, 1) (``None``: no measurement);
    ``m0``, ``P0``: the first state's prior. Returns smoothed means (P, 6) and covariances (P, 6, 6). Several
    measurement sets at once (the gains are theirs in common): ``y[t]`` (m_t, D) and ``m0`` (6, D), means
    (P, 6, D)."""
    P_n = len(t_s)
    mf, Pf = np.zeros((P_n,) + np.shape(m0)), np.zeros((P_n, 6, 6))
    mp, Pp = np.zeros((P_n,) + np.shape(m0)), np.zeros((P_n, 6, 6))
    Fs = [None] * P_n
    m, C = np.asarray(m0, float), np.asarray(P0, float)
    for t in range(P_n):
        if t:
            F, Q = motion.transition(t_s[t] - t_s[t - 1])
            Fs[t] = F
            m, C = F @ m, F @ C @ F.T + Q
        mp[t], Pp[t] = m, C
        if H[t] is not None:
            Hs = np.zeros((len(y[t]), 6))
            Hs[:, :3] = H[t]
            S = Hs @ C @ Hs.T + np.eye(len(y[t]))
            K = np.linalg.solve(S, Hs @ C).T
            m = m + K @ (y[t] - Hs @ m)
            A = np.eye(6) - K @ Hs
            C = A @ C @ A.T + K @ K.T   # Joseph form: stays symmetric and positive
        mf[t], Pf[t] = m, C
    ms, Ps = mf.copy(), Pf.copy()
    for t in range(P_n - 2, -1, -1):
        G = np.linalg.solve(Pp[t + 1], Fs[t + 1] @ Pf[t]).T
        ms[t] = mf[t] + G @ (ms[t + 1] - mp[t + 1])
        Ps[t] = Pf[t] + G @ (Ps[t + 1] - Pp[t + 1]) @ G.T
    return ms, 0.5 * (Ps + np.swapaxes(Ps, 1, 2))


def _whiten(currents, noise_rel):
    return 1.0 / (noise_rel * np.abs(currents))


def posterior_crb(jacobian: np.ndarray, currents: np.ndarray, t_s: np.ndarray, motion: MotionModel,
                  noise_rel: float, passes=None, round_tank_poses=None) -> np.ndarray:
    """(P, 3, 3) posterior Cramer-Rao bound of (x, y, heading) for the track whose Jacobians are ``jacobian``
    (P, m, 3), the measurement noise ``noise_rel`` relative to ``currents`` (P, m) and the motion prior
    (module doc); ``passes``: index arrays of the passes (default: one). NaN Jacobians: no measurement there.
    ``round_tank_poses`` (P, 3): in a round tank, the track, whose first pose gives the angle about the axis
    (:func:`first_state_prior`)."""
    jacobian, currents = np.asarray(jacobian, float), np.asarray(currents, float)
    w = _whiten(currents, noise_rel)
    out = np.full((len(currents), 3, 3), np.nan)
    for idx in passes or [np.arange(len(currents))]:
        H = [None if not np.isfinite(jacobian[i]).all() else w[i][:, None] * jacobian[i] for i in idx]
        y = [None if h is None else np.zeros(len(h)) for h in H]
        start = np.zeros(3) if round_tank_poses is None else np.asarray(round_tank_poses, float)[idx[0]]
        m0, P0 = first_state_prior(start, round_tank_poses is not None)
        _, Ps = rts_smoother(H, y, np.asarray(t_s, float)[idx], motion, m0, P0)
        out[idx] = Ps[:, :3, :3]
    return out


def expected_error(jacobian: np.ndarray, currents: np.ndarray, t_s: np.ndarray, motion: MotionModel,
                   noise_rel: float, truth: np.ndarray, passes=None, draws: int = 64, seed: int = 0,
                   round_tank: bool = False):
    """This estimator's own error on the track ``truth`` (P, 3), linearised there: its bias (what the motion prior
    takes off a track it does not expect: zero on a straight pass at constant speed) (P, 3), and the RMS of its
    noise error (P, 3), from ``draws`` noise draws through the linear smoother (whose gains they share).

    The posterior bound (:func:`posterior_crb`) averages over every track the prior allows; on one given track
    the estimator does better than it where the track costs the prior little, and worse where the prior's bias
    is large. Beside the bound this says which: an error above this one is the model's. ``round_tank``: the first
    pose of each pass gives the angle about the axis (:func:`first_state_prior`)."""
    jacobian, currents, truth = (np.asarray(a, float) for a in (jacobian, currents, truth))
    w = _whiten(currents, noise_rel)
    rng = np.random.default_rng(seed)
    bias, spread = np.full((len(truth), 3), np.nan), np.full((len(truth), 3), np.nan)
    for idx in passes or [np.arange(len(currents))]:
        H, y = [], []
        for i in idx:
            if not np.isfinite(jacobian[i]).all():
                H.append(None)
                y.append(None)
                continue
            A = w[i][:, None] * jacobian[i]
            H.append(A)
            exact = A @ truth[i]
            y.append(np.c_[exact, exact[:, None] + rng.standard_normal((len(exact), draws))])
        m0, P0 = first_state_prior(truth[idx[0]], round_tank)
        m0 = np.repeat(m0[:, None] if round_tank else np.zeros((6, 1)), draws + 1, axis=1)
        ms, _ = rts_smoother(H, y, np.asarray(t_s, float)[idx], motion, m0, P0)
        bias[idx] = ms[:, :3, 0] - truth[idx]
        spread[idx] = np.sqrt(np.mean((ms[:, :3, 1:] - ms[:, :3, :1]) ** 2, axis=2))
    return bias, spread


@dataclass
class SmoothedTrack:
    """The maximum a posteriori track of a log (module doc) and what the fit says of it."""

    poses: np.ndarray  # (P, 3) x_m, y_m, yaw_rad
    velocities: np.ndarray  # (P, 3) m/s, m/s, rad/s
    covariance: np.ndarray  # (P, 3, 3) posterior covariance of each pose at the estimate (linearised)
    chi2: np.ndarray  # (P,) whitened residual sum of squares at the estimate (NaN: the model refuses the pose)
    iterations: int
    converged: bool
    cost: float  # -2 log posterior (up to a constant) at the estimate


def _model_at(model, q):
    """(I, J) of ``model`` at ``q`` (P, 3), NaN rows where the model refuses a pose (tried one by one only when the
    whole call is refused)."""
    res = model(q)
    if res is not None:
        return res
    I_rows, J_rows = [], []
    for p in q:
        r = model(p[None])
        I_rows.append(None if r is None else r[0][0])
        J_rows.append(None if r is None else r[1][0])
    good = next((i for i in I_rows if i is not None), None)
    if good is None:
        return np.full((len(q), 0), np.nan), np.full((len(q), 0, 3), np.nan)
    m = len(good)
    I = np.array([np.full(m, np.nan) if i is None else i for i in I_rows])
    J = np.array([np.full((m, 3), np.nan) if j is None else j for j in J_rows])
    return I, J


#: a pose the model refuses costs as much as a residual of 5 sigma on every receiver (and brings no information)
_REFUSED_CHI2_PER_RECEIVER = 25.0


def _cost(model, s, currents, w, t_s, motion, m0, P0inv):
    I, J = _model_at(model, s[:, :3])
    m = currents.shape[1]
    if I.shape[1] == 0:
        chi2 = np.full(len(s), np.nan)
    else:
        r = w * (I - currents)
        chi2 = np.sum(r**2, axis=1)
    d0 = s[0] - m0
    total = (np.nansum(chi2) + _REFUSED_CHI2_PER_RECEIVER * m * np.isnan(chi2).sum() + motion.cost(s, t_s)
             + float(d0 @ P0inv @ d0))
    return total, chi2, I, J


def _within_the_model(model, before: np.ndarray, after: np.ndarray, halvings: int = 12) -> np.ndarray:
    """The state ``after``, or, where the model refuses its pose (beyond a wall: a model that misfits by far more
    than the noise pulls an update there), the farthest point towards it from ``before`` that the model takes,
    halving the update up to ``halvings`` times; ``before`` if none."""
    step = after - before
    for k in range(halvings + 1):
        trial = before + 0.5**k * step
        if model(trial[None, :3]) is not None:
            return trial
    return before


def _filter_init(model, currents, noise_rel, t_s, start, motion, inner: int = 2, round_tank: bool = False):
    """The first iterate: an iterated extended Kalman filter forward pass (each update Gauss-Newton on the
    sample's currents and the predicted state, up to ``inner`` times), from the per-sample maximum likelihood
    of the first sample started at ``start``, then the linear smoother of its last linearisations; (P, 6)."""
    w = _whiten(currents, noise_rel)
    first = track(model, currents[:1], start, noise_rel if np.ndim(noise_rel) == 0 else noise_rel[:1]).poses[0]
    q0 = np.asarray(start, float) if not np.isfinite(first).all() or round_tank else first
    m, C = first_state_prior(q0, round_tank)
    H, y, filtered = [], [], []
    for t in range(len(currents)):
        if t:
            F, Q = motion.transition(t_s[t] - t_s[t - 1])
            m, C = F @ m, F @ C @ F.T + Q
        res = model(m[None, :3])
        if res is None and filtered:   # the prediction runs beyond a wall: from the last state, at rest
            m = np.r_[filtered[-1][:3], np.zeros(3)]
            res = model(m[None, :3])
        m_pred, C_pred, q, Ht, yt = m, C, m[:3], None, None
        for k in range(inner):
            res = res if k == 0 else model(q[None])
            if res is None:
                break
            A = w[t][:, None] * res[1][0]
            Ht, yt = A, w[t] * (currents[t] - res[0][0]) + A @ q
            Hs = np.c_[A, np.zeros_like(A)]
            S = Hs @ C_pred @ Hs.T + np.eye(len(yt))
            K = np.linalg.solve(S, Hs @ C_pred).T
            m = m_pred + K @ (yt - Hs @ m_pred)
            done = np.max(np.abs(m[:3] - q) / np.sqrt(np.diag(C_pred)[:3])) < 1e-3
            q = m[:3]
            if done:
                break
        if Ht is not None:
            Hs = np.c_[Ht, np.zeros_like(Ht)]
            S = Hs @ C_pred @ Hs.T + np.eye(len(yt))
            K = np.linalg.solve(S, Hs @ C_pred).T
            m = _within_the_model(model, m_pred, m_pred + K @ (yt - Hs @ m_pred))
            A_ = np.eye(6) - K @ Hs
            C = A_ @ C_pred @ A_.T + K @ K.T
        H.append(Ht)
        y.append(yt)
        filtered.append(m)
    ms, _ = rts_smoother(H, y, t_s, motion, *first_state_prior(q0, round_tank))
    # the smoother of linearisations can carry a state where the model refuses it: the filter's state there
    I = _model_at(model, ms[:, :3])[0]
    refused = np.isnan(I).any(axis=1) if I.shape[1] else np.ones(len(ms), bool)
    ms[refused] = np.asarray(filtered)[refused]
    return ms


def _linearised(I, J, s, currents, w):
    """The whitened measurements linearised at the states ``s``: lists of H (m, 3) and y (m,) (None: refused)."""
    H, y = [], []
    for i in range(len(s)):
        if I.shape[1] == 0 or not np.isfinite(I[i]).all():
            H.append(None)
            y.append(None)
            continue
        A = w[i][:, None] * J[i]
        H.append(A)
        y.append(w[i] * (currents[i] - I[i]) + A @ s[i, :3])
    return H, y


def _gauss_newton(model, s, currents, w, t_s, motion, max_iter, tol, prior=None):
    """Gauss-Newton with a backtracking line search on -2 log posterior from the states ``s``; (s, chi2, cost,
    iterations, converged). ``prior``: (m0, P0) of the first state (default: diffuse about ``s[0]``)."""
    m0, P0 = (s[0].copy(), np.diag(DIFFUSE_SIGMA**2)) if prior is None else prior
    P0inv = np.linalg.inv(P0)
    cost, chi2, I, J = _cost(model, s, currents, w, t_s, motion, m0, P0inv)
    converged, it = False, 0
    while it < max_iter:
        it += 1
        ms, Ps = rts_smoother(*_linearised(I, J, s, currents, w), t_s, motion, m0, P0)
        step = ms - s
        sd = np.sqrt(np.maximum(np.einsum("pii->pi", Ps), 1e-300))
        small = np.max(np.abs(step) / sd) < tol   # the step in units of its own posterior spread
        alpha, accepted = 1.0, False
        while alpha > 1e-3:
            trial = s + alpha * step
            c_new, chi2_new, I_new, J_new = _cost(model, trial, currents, w, t_s, motion, m0, P0inv)
            # never a step that takes more poses where the model refuses them: where a model misfits by more than
            # the refusal's charge (the PSM a few per cent off, hundreds of sigma), the track would leave the tank
            if c_new <= cost and np.isnan(chi2_new).sum() <= np.isnan(chi2).sum():
                accepted = True
                break
            alpha *= 0.5
        if not accepted:   # no descent along the step: at the minimum if the step was small, else stalled
            converged = small
            break
        s, cost, chi2, I, J = trial, c_new, chi2_new, I_new, J_new
        if small:
            converged = True
            break
    return s, chi2, cost, it, converged, (I, J)


#: stiffer motion priors solved first, each from the last (continuation): a weak prior lets the track slide along a
#: wall into a false minimum from a poor start; a stiff one holds it, and relaxing it step by step stays in its basin
CONTINUATION = (1e-4, 1e-2, 1.0)


def _smooth_pass(model, currents, t_s, start, motion, noise_rel, max_iter, tol, round_tank=False):
    w = _whiten(currents, noise_rel)
    its, s = 0, None
    prior = first_state_prior(start, True) if round_tank else None
    for f in CONTINUATION:
        stage = MotionModel(f * motion.acceleration_psd_m2_per_s3, f * motion.turn_psd_rad2_per_s3)
        s = _filter_init(model, currents, noise_rel, t_s, start, stage, round_tank=round_tank) if s is None else s
        s, chi2, cost, it, converged, (I, J) = _gauss_newton(model, s, currents, w, t_s, stage, max_iter, tol,
                                                             prior)
        its += it
    # the posterior covariance at the estimate
    _, Ps = rts_smoother(*_linearised(I, J, s, currents, w), t_s, motion,
                         *(prior or (s[0], np.diag(DIFFUSE_SIGMA**2))))
    return s, Ps[:, :3, :3], chi2, its, converged, cost


def smooth_track(model, currents: np.ndarray, t_s: np.ndarray, start, motion: MotionModel | None = None,
                 noise_rel: float = 5e-4, passes=None, max_iter: int = 30, tol: float = 1e-3,
                 round_tank: bool = False) -> SmoothedTrack:
    """The maximum a posteriori track of a log under ``motion`` (module doc).

    Parameters
    ----------
    model : callable
        ``q (k, 3) -> (I (k, m), dI/dq (k, m, 3))``, or ``None`` where a pose is outside what the model covers.
    currents : (P, m)
        Measured receiver currents, in the model's units.
    t_s : (P,)
        Time of each sample (s), increasing within a pass.
    start : (3,)
        The pose the iteration starts from (the first logged one): it picks among mirror-image tracks, it is not
        information (the first state's prior is diffuse).
    noise_rel : float or (P, m) array
        Relative noise of a current (1 sigma), one for all or one per current.
    passes : list of index arrays, optional
        The passes, each its own chain, in time order (default: one pass); each but the first starts from the
        previous pass's last estimate.
    tol : float
        Converged when a full Gauss-Newton step moves every state by less than this many of its posterior sigmas.
    round_tank : bool
        The model is the same at every rotation of the pose about the tank's axis (a round tank's): ``start``
        then gives the angle about it (:func:`first_state_prior`), which the currents cannot.
    """
    motion = motion or MotionModel()
    currents = np.asarray(currents, float)
    t_s = np.asarray(t_s, float)
    P_n = len(currents)
    poses, vel = np.full((P_n, 3), np.nan), np.full((P_n, 3), np.nan)
    cov, chi2 = np.full((P_n, 3, 3), np.nan), np.full(P_n, np.nan)
    its, conv, cost = 0, True, 0.0
    q_start = np.asarray(start, float)
    for idx in passes or [np.arange(P_n)]:
        idx = np.asarray(idx)
        spread = noise_rel if np.ndim(noise_rel) == 0 else np.asarray(noise_rel, float)[idx]
        s, C, c2, it, ok, c = _smooth_pass(model, currents[idx], t_s[idx], q_start, motion, spread, max_iter, tol,
                                           round_tank)
        poses[idx], vel[idx], cov[idx], chi2[idx] = s[:, :3], s[:, 3:], C, c2
        its, conv, cost = max(its, it), conv and ok, cost + c
        q_start = s[-1, :3]
    return SmoothedTrack(poses, vel, cov, chi2, its, conv, cost)
