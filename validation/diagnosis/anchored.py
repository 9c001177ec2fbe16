"""The default baseline of the diagnosis: the BEM at adaptive anchor poses, interpolated over pose, cached on disk.

The diagnosis may only blame the water for a gap that the model does not
make itself. The BEM is the reference; the PSM is fast but off it by up to
several percent near the walls, which is twenty times the bench noise. Here:

1. the calibrated PSM is evaluated at every logged pose where it can be (it
   refuses poses where one of its spheres crosses a wall: with nothing
   cached, those poses are the first anchors, near the walls where the tank
   matters most; with the PSM as base, below, they must be);
2. the BEM (:class:`electrosense.bem.PoseSweep`, built once per scene) is run at a first
   spread of *anchor* poses, dense where the tank's effect changes fastest;
3. the ratio log(K_bem / K_ref) of every entry of K is interpolated over pose
   space (cubic radial basis functions of the sensor's tip positions, with a
   linear trend), and its leave-one-out error at every anchor is computed in
   closed form (Rippa's formula). The reference ``K_ref`` (the *base*) is the
   PSM or the free-space K (a constant: the BEM interpolated by itself),
   whichever predicts the BEM better at the anchors, by that leave-one-out
   error: near the walls the calibrated PSM can be off the BEM by more, and
   more sharply, than the tank changes K (5-electrode sensor, tip 1.5 cm from
   a wall: 1.5 % RMS leave-one-out error with the PSM base, 0.1 % with the
   free one); the choice is made again at every round, on the anchors;
4. the estimated error of each sample (the leave-one-out error of its nearest
   anchors scaled by its distance from them, :func:`estimated_error`: an
   upper estimate, the anchors being denser with the pose back in; zero at
   the anchors themselves) is compared with ``target`` (a third of the
   bench noise by default); while the RMS error, over all samples or over any
   region of the tank, exceeds it, the BEM is run at the samples of largest
   estimated error, up to every logged pose (then the baseline *is* the BEM).

The BEM's answers are kept on disk (:class:`AnchorStore`), keyed by a hash of
the sensor's geometry, the tank, the known objects, the BEM's settings and
the model code's version (never by the sensor's name), at unit conductivity
(K is proportional to sigma); a later log of the same sensor in the same tank
reuses them and runs the BEM only where they do not reach.

Example
-------
>>> import numpy as np
>>> X = np.linspace(0, 1, 9)[:, None]
>>> y = np.sin(3 * X)
>>> interp = RBFInterpolant(X, y)
>>> float(np.abs(interp(np.array([[0.3]])) - np.sin(0.9)).max()) < 1e-2
True
>>> bool(np.abs(interp.leave_one_out).max() < 0.05)
True
"""
from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from electrosense.bem.block_cache import cache_root
from electrosense.bem.conductance import pair_values
from electrosense.meshes.tank import TANK_REGIONS, Tank
from electrosense.validation.diagnosis.forward import receiver_currents

__all__ = ["RBFInterpolant", "AnchorStore", "AnchoredBaseline", "anchored_baseline", "pose_features", "same_pose_groups",
           "psm_usable", "anchor_cache_dir", "estimated_error", "SENSOR_EDGE_FACTOR", "default_bem_options"]

#: sensor mesh edge of the anchors' BEM, in units of the mesher's default: the per-pose cost is the tank's
#: Schur complement plus O(N_sensor^2); with the free-space edge correction a coarser sensor mesh moves K by
#: about 2e-4 mid-tank, 1e-3 with a tip 1.5 cm from a wall (5-electrode sensor, factors 2 against 3), which
#: the budget's discretisation estimate reports
SENSOR_EDGE_FACTOR = 3.0

#: what an anchor entry holds (K, the focus, the discretisation check, the pose gradient's nodes, the walls'
#: shape derivatives): a new format is a new entry
ANCHOR_FORMAT = 2

#: a cached BEM pose this close to a logged one (m, the distance between their tip positions) is carried to it
#: by its own derivatives (:func:`_carry_cached`)
DERIVATIVE_REUSE_M = 1e-3

#: interpolation nodes closer than this (m, every tip coordinate) are merged into one
NODE_MERGE_M = 5e-4

#: CPU seconds (this process) of BEM poses after which no more anchors are added (the estimated error is then
#: reported as it stands, and raises the noise floor); CPU, not wall-clock: on a machine busy with other work the
#: same log gets the same anchors and the same answer
MAX_BEM_SECONDS = 480.0


def default_bem_options(sensor, options: dict | None = None) -> dict:
    """The anchors' BEM options: ``options`` with the sensor edge length defaulting to
    :data:`SENSOR_EDGE_FACTOR` times the mesher's default."""
    from electrosense.meshes.sensor_mesh import default_edge_length_m

    out = dict(options or {})
    if out.get("edge_length_m") is None:
        out["edge_length_m"] = SENSOR_EDGE_FACTOR * default_edge_length_m(sensor)
    return out


# ------------------------------------------------------------------ interpolation
#: the RBF's linear trend spans the directions of the feature space along which the nodes spread by more than this
#: (RMS, m): a few millimetres, well above a robot's position noise and well below a pass's length
TREND_MIN_SPREAD_M = 5e-3


class RBFInterpolant:
    """Polyharmonic radial basis interpolation with a polynomial trend, and its leave-one-out errors.

    ``degree`` 1: phi = r^3 with a linear trend; ``degree`` 2: phi = r^5 with a
    quadratic trend, which converges faster on smooth data (a tank map of a
    random 5-electrode sensor, 400 BEM poses: 0.020 % RMS at fresh poses
    against 0.029 % with r^3, and 0.056 % against 0.072 % with 200); with
    fewer nodes than the trend has terms, the degree falls to 1 (and the trend
    to a constant below that). ``leave_one_out`` (B, k) is the error of
    predicting each node from all the others, in closed form: e_i = c_i /
    (M^-1)_ii with M the augmented interpolation matrix (Rippa 1999). The
    trend is in every feature (``min_trend_spread_m`` None), or only along the
    directions along which the nodes spread by more than
    ``min_trend_spread_m`` (RMS; the anchored baseline's
    :data:`TREND_MIN_SPREAD_M`): passes at one heading and depth lie near a
    line of the feature space, and a trend along the robot's position noise (a
    tenth of a millimetre) is fitted to that noise, its leave-one-out errors
    changing several-fold from one log of the same path to the next.

    ``regressors`` (B, r): more trend columns, known wherever the interpolant
    is evaluated (passed again to :meth:`__call__` and
    :meth:`value_and_gradient`), such as a cheaper model's values there: the
    interpolant is then a linear function of them plus a smooth remainder,
    fitted together, the leave-one-out errors included (the linear
    multi-fidelity form of Kennedy & O'Hagan 2000, *Biometrika* 87(1), 1). A
    tank map's correction from its coarse to its reference sensor mesh, as a
    function of the coarse K, came 1.1-5x closer at left-out nodes than as a
    function of the pose alone (four maps, 12-60 reference poses).

    ``groups`` (B,): rows that are one datum, left out together (a node and
    its mirror images across a symmetry plane, which carry its value: left
    in, they would predict the node from itself). A group's error is the
    block form of Rippa's formula, e_G = ((M^-1)_GG)^-1 c_G, each row's
    error that of its group left out.

    Example
    -------
    Nodes on a line, jittered by 0.1 mm across it: the trend is along the line only.

    >>> rng = np.random.default_rng(0)
    >>> X = np.c_[np.linspace(0, 0.3, 9), 1e-4 * rng.standard_normal(9)]
    >>> f = RBFInterpolant(X, np.sin(10 * X[:, :1]), min_trend_spread_m=TREND_MIN_SPREAD_M)
    >>> f.axes.shape, bool(np.abs(f.leave_one_out).max() < 0.05)
    ((2, 1), True)

    The quintic on a smooth function of two variables, with its gradient:

    >>> X = rng.uniform(-1, 1, (60, 2))
    >>> f = RBFInterpolant(X, np.sin(X[:, :1]) * X[:, 1:], degree=2)
    >>> v, g = f.value_and_gradient(np.array([[0.2, 0.5]]))
    >>> f.power, bool(abs(v[0, 0] - np.sin(0.2) * 0.5) < 1e-3)
    (5, True)
    >>> bool(np.allclose(g[0, :, 0], [np.cos(0.2) * 0.5, np.sin(0.2)], atol=1e-2))
    True

    A function that is a cheaper model's values, scaled, plus a slow remainder:

    >>> cheap = np.sin(3 * X[:, :1])
    >>> f = RBFInterpolant(X, 0.2 * cheap + 0.01 * X[:, 1:], regressors=cheap)
    >>> Xn = np.array([[0.3, -0.4]])
    >>> bool(abs(f(Xn, regressors=np.sin(3 * Xn[:, :1]))[0, 0] - (0.2 * np.sin(0.9) - 0.004)) < 1e-6)
    True
    """

    def __init__(self, X: np.ndarray, y: np.ndarray, min_trend_spread_m: float | None = None, degree: int = 1,
                 regressors: np.ndarray | None = None, groups: np.ndarray | None = None):
        self.X = np.asarray(X, float)
        y = np.asarray(y, float)
        self.shape = y.shape[1:]
        Y = y.reshape(len(y), -1)
        B, d = self.X.shape
        R = np.zeros((B, 0)) if regressors is None else np.asarray(regressors, float).reshape(B, -1)
        self.n_regressors = R.shape[1]
        if min_trend_spread_m is None:      # every feature (the trend [1, X, ...] that stored coefficients assume)
            self.centre, self.axes = np.zeros(d), np.eye(d)
        else:                               # the directions the nodes span
            self.centre = self.X.mean(axis=0)
            _, spread, Vt = np.linalg.svd(self.X - self.centre, full_matrices=False)
            self.axes = Vt[spread / np.sqrt(B) > min_trend_spread_m].T   # (d, t)
        t = self.axes.shape[1]
        self.degree = int(degree)
        while self.degree > 1 and B <= trend_terms(t, self.degree) + self.n_regressors + 1:
            self.degree -= 1
        self.linear = B > t + self.n_regressors + 2
        Pm = np.hstack([self._trend(self.X), R])
        q = Pm.shape[1]
        M = np.zeros((B + q, B + q))
        M[:B, :B] = self._phi(self.X, self.X)
        M[:B, B:] = Pm
        M[B:, :B] = Pm.T
        Minv = np.linalg.pinv(M, rcond=1e-13, hermitian=True)
        rhs = np.vstack([Y, np.zeros((q, Y.shape[1]))])
        self.coef = Minv @ rhs
        diag = np.diag(Minv)[:B]
        loo = self.coef[:B] / np.where(np.abs(diag) > 0, diag, np.inf)[:, None]
        if groups is not None:   # rows of one datum left out together: the block form of Rippa's formula
            groups = np.asarray(groups)
            if groups.shape != (B,):
                raise ValueError(f"groups must give one label per node ({B}), got shape {groups.shape}")
            _, inverse, counts = np.unique(groups, return_inverse=True, return_counts=True)
            for g in np.flatnonzero(counts > 1):
                rows = np.flatnonzero(inverse == g)
                loo[rows] = np.linalg.lstsq(Minv[np.ix_(rows, rows)], self.coef[rows], rcond=None)[0]
        self.leave_one_out = loo.reshape((B,) + self.shape)

    @classmethod
    def from_coefficients(cls, X: np.ndarray, coef: np.ndarray, n_regressors: int = 0) -> "RBFInterpolant":
        """The interpolant of stored nodes ``X`` (B, d) and coefficients ``coef`` (B + q + r, k), the trend in
        every feature, then ``n_regressors`` r; its degree (and kernel) read from the number of trend terms q."""
        self = cls.__new__(cls)
        self.X, self.coef = np.asarray(X, float), np.asarray(coef, float)
        self.n_regressors = int(n_regressors)
        B, d = self.X.shape
        q = len(self.coef) - B - self.n_regressors
        self.centre, self.axes, self.shape = np.zeros(d), np.eye(d), self.coef.shape[1:]
        self.linear, self.degree = q > 1, 2 if q == trend_terms(d, 2) else 1
        if q not in (1, trend_terms(d, 1), trend_terms(d, 2)):
            raise ValueError(f"{q} trend coefficients fit no trend of {d} features")
        return self

    @property
    def regressor_coefficients(self) -> np.ndarray:
        """(r, k): the regressors' coefficients (each output a linear function of them plus the rest)."""
        c = self.coef.reshape(len(self.coef), -1)
        return c[len(c) - self.n_regressors:]

    @property
    def power(self) -> int:
        """The kernel's power: phi = r ** power (3, or 5 with a quadratic trend)."""
        return 2 * self.degree + 1

    @staticmethod
    def _distance(A, B):
        return np.sqrt(np.maximum(np.sum(A**2, axis=1)[:, None] + np.sum(B**2, axis=1)[None, :] - 2.0 * A @ B.T, 0.0))

    def _phi(self, A, B):
        return self._distance(A, B) ** self.power

    def _trend(self, X):
        ones = np.ones((len(X), 1))
        if not self.linear:
            return ones
        Z = (X - self.centre) @ self.axes
        if self.degree == 1:
            return np.hstack([ones, Z])
        i, j = np.triu_indices(Z.shape[1])
        return np.hstack([ones, Z, Z[:, i] * Z[:, j]])

    def _regressors(self, X, regressors, name="regressors"):
        if self.n_regressors == 0:
            return np.zeros((len(X), 0))
        if regressors is None:
            raise ValueError(f"this interpolant has {self.n_regressors} regressors: pass their values as {name}")
        return np.asarray(regressors, float).reshape(len(X), -1)

    def __call__(self, X: np.ndarray, regressors: np.ndarray | None = None) -> np.ndarray:
        """Values at ``X`` (p, d) (the regressors' values there, (p, r), where the interpolant has them)."""
        X = np.asarray(X, float)
        A = np.hstack([self._phi(X, self.X), self._trend(X), self._regressors(X, regressors)])
        return (A @ self.coef).reshape((len(X),) + self.shape)

    def value_and_gradient(self, X: np.ndarray, regressors: np.ndarray | None = None,
                           regressor_gradient: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Values (p, k) and their gradient by the features (p, d, k) at ``X`` (p, d), one vectorised call
        (with regressors: their values (p, r) and gradient by the features (p, d, r) there)."""
        X = np.asarray(X, float)
        B = len(self.X)
        c = self.coef.reshape(len(self.coef), -1)
        r_ = self.n_regressors
        cb, ct, cr = c[:B], c[B:len(c) - r_], self.regressor_coefficients
        R = self._regressors(X, regressors)
        r = self._distance(X, self.X)
        values = (r**self.power) @ cb + self._trend(X) @ ct + R @ cr
        # d/dX_j sum_b r_b^p c_b = p sum_b r_b^(p-2) (X_j - X_bj) c_b
        w = self.power * r ** (self.power - 2)
        G = X[:, :, None] * (w @ cb)[:, None, :] - np.stack([w @ (self.X[:, j, None] * cb) for j in range(X.shape[1])],
                                                           axis=1)
        if self.linear:
            Z = (X - self.centre) @ self.axes
            t = Z.shape[1]
            dT = np.zeros((len(X), t, len(ct)))            # d trend / d Z
            dT[:, np.arange(t), 1 + np.arange(t)] = 1.0
            if self.degree == 2:
                i, j = np.triu_indices(t)
                k = 1 + t + np.arange(len(i))
                dT[:, i, k] += Z[:, j]
                dT[:, j, k] += Z[:, i]
            G = G + np.einsum("dt,ptq,qk->pdk", self.axes, dT, ct)
        if r_:
            dR = self._regressors(X, regressor_gradient, "regressor_gradient").reshape(len(X), -1, r_)
            G = G + np.einsum("pdr,rk->pdk", dR, cr)
        return values, G


def trend_terms(n_features: int, degree: int) -> int:
    """The number of monomials of total degree at most ``degree`` in ``n_features`` variables (1, 1 + d, ...).

    >>> trend_terms(4, 1), trend_terms(4, 2)
    (5, 15)
    """
    from math import comb

    return comb(n_features + degree, degree)


def pose_features(sensor, poses: np.ndarray) -> np.ndarray:
    """(P, 6): the tank-frame positions (m) of the sensor's two tips, a metric on poses that includes the heading."""
    from electrosense.meshes.pose import sensor_to_tank

    tips = np.array([[0.5 * sensor.length_m, 0.0, 0.0], [-0.5 * sensor.length_m, 0.0, 0.0]])
    return sensor_to_tank(tips, np.asarray(poses, float)).reshape(len(poses), 6)


def psm_usable(model, poses: np.ndarray, tank) -> np.ndarray:
    """(P,) bool: poses where every sphere of the PSM ``model`` lies inside the water (the PSM refuses the others);
    none in a tank the PSM has no images of (a cylinder)."""
    from electrosense.psm.conductance import sphere_centres_m
    from electrosense.psm.images import has_images

    if tank is None:
        return np.ones(len(poses), bool)
    if not has_images(tank):
        return np.zeros(len(poses), bool)
    X = sphere_centres_m(model, np.asarray(poses, float))
    gap = tank.distance_to_boundary_m(X) - np.asarray(model.radii_m)[None, :, None]
    return np.all(gap > 1e-4, axis=(1, 2))


# --------------------------------------------------------------------- the store
def anchor_cache_dir() -> Path:
    """``diagnosis-anchors`` under the one cache root (:func:`electrosense.bem.block_cache.cache_root`)."""
    return cache_root() / "diagnosis-anchors"


@dataclass
class AnchorStore:
    """BEM conductances (at 1 S/m) of one sensor in one scene, on disk; one entry per tank mesh (focus).

    The file name is a hash of the sensor's geometry (its name left out), the
    tank, the objects, the BEM options and :func:`electrosense.validation.simulation.models.code_version`.
    """

    sensor: object
    tank: object
    objects: tuple = ()
    bem_options: dict = field(default_factory=dict)
    folder: Path | None = None

    def __post_init__(self):
        from electrosense.validation.simulation.models import code_version

        geometry = {k: v for k, v in self.sensor.to_dict().items() if k not in ("name", "notes")}
        text = json.dumps({"sensor": geometry, "tank": repr(self.tank), "objects": repr(tuple(self.objects)),
                           "bem": {k: repr(v) for k, v in sorted(self.bem_options.items())},
                           "code": code_version(), "format": ANCHOR_FORMAT}, sort_keys=True)
        self.key = hashlib.sha256(text.encode()).hexdigest()[:24]
        self.folder = Path(self.folder) if self.folder is not None else anchor_cache_dir()

    @property
    def path(self) -> Path:
        return self.folder / f"{self.key}.npz"

    def load(self) -> dict | None:
        """``{"poses", "K_unit", "focus_m", "bem_error"}`` or None."""
        try:
            with np.load(self.path) as z:
                return {k: z[k] for k in z.files}
        except (OSError, ValueError, KeyError, EOFError):
            return None

    def save(self, entry: dict) -> None:
        """Write atomically (a concurrent reader sees the old entry or the new one); a failure only warns."""
        import warnings

        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            partial = self.path.with_name(f"{self.key}.{os.getpid()}.partial.npz")
            np.savez(partial, **entry)
            os.replace(partial, self.path)
        except OSError as exc:
            warnings.warn(f"BEM anchors not cached ({exc})", RuntimeWarning, stacklevel=2)


# ----------------------------------------------------------------------- baseline
@dataclass
class AnchoredBaseline:
    """The corrected baseline at the logged poses and what is known of its error."""

    K: np.ndarray  # (P, n, n) at the observations' conductivity
    error: np.ndarray  # (P, m) estimated relative error of the receiver currents (0 at BEM poses)
    anchors: np.ndarray  # (A,) sample indices computed by the BEM (new or from the cache)
    refused: np.ndarray  # (R,) sample indices the PSM refuses (covered by the BEM)
    n_bem_new: int
    n_cached: int
    target: float
    rounds: list
    psm_vs_bem_rms: float
    loo_rms: float
    seconds: float
    bem_error: np.ndarray | None = None  # (P, m) estimated discretisation error of the BEM itself
    stopped: str = ""
    base: str = "psm"  # what the BEM's ratio was interpolated against: the PSM, or the free-space K ("free")
    pose_gradient: object = None  # the BEM's d log K / d(x, y, yaw) at the logged poses (:mod:`.pose_gradient`)
    wall_derivatives: np.ndarray | None = None  # (P, regions, n, n) dK per metre each tank region moves out (NaN off
    #                                              the BEM poses; at the observations' conductivity)
    wall_regions: tuple = ()
    focus_m: np.ndarray | None = None  # the points the BEM's tank mesh was graded towards
    bem_sweep: object = None  # () -> the anchors' PoseSweep (sigma 1 S/m, their tank mesh), built on first call

    @property
    def interpolation_rms(self) -> float:
        return float(np.sqrt(np.mean(self.error**2)))

    @property
    def total_error(self) -> np.ndarray:
        """(P, m): interpolation and BEM discretisation errors in quadrature."""
        return self.error if self.bem_error is None else np.hypot(self.error, self.bem_error)

    @property
    def rms_error(self) -> float:
        return float(np.sqrt(np.mean(self.total_error**2)))


def _offdiag_log_ratio(K_bem, K_psm, emitter: int):
    """log(K_bem / K_psm) of every pair (:func:`~electrosense.bem.conductance.pair_values`: the emitter's column,
    the receiver currents the bench reads)."""
    a, b = pair_values(K_bem, emitter), pair_values(K_psm, emitter)
    if np.any(a / b <= 0):
        raise ValueError("the BEM and the PSM disagree in the sign of a transfer conductance")
    return np.log(a / b)


def _apply_log_ratio(K_psm, L, emitter: int):
    """The symmetric K whose pairs are ``K_psm``'s (:func:`~electrosense.bem.conductance.pair_values`) times
    exp(L), zero row sums."""
    n = K_psm.shape[-1]
    iu = np.triu_indices(n, 1)
    K = np.zeros(np.shape(K_psm))
    K[:, iu[0], iu[1]] = pair_values(K_psm, emitter) * np.exp(L)
    K[:, iu[1], iu[0]] = K[:, iu[0], iu[1]]
    off = K * (1 - np.eye(n))
    return off - np.eye(n) * off.sum(axis=-1, keepdims=True)


def _receiver_entries(sensor):
    """Positions, in the upper-triangle list, of the entries (receiver, emitter)."""
    n, e = sensor.n_electrodes, sensor.emitter - 1
    iu = list(zip(*np.triu_indices(n, 1)))
    return [iu.index((min(k, e), max(k, e))) for k in range(n) if k != e]


def same_pose_groups(features: np.ndarray, tol_m: float = 5e-5) -> np.ndarray:
    """(P,) labels: samples whose poses coincide (every tip coordinate within ``tol_m``) share one, numbered in
    order of first appearance (passes that repeat a path log the same nominal poses: one BEM solve serves them all).

    Example
    -------
    >>> F = np.array([[0, 0, 0, 1, 0, 0], [0.1, 0, 0, 1.1, 0, 0], [0, 0, 0, 1, 0, 0]], float)
    >>> same_pose_groups(F).tolist()
    [0, 1, 0]
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    F = np.asarray(features, float)
    pairs = cKDTree(F).query_pairs(tol_m, p=np.inf, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(F), len(F)))
    _, labels = connected_components(graph, directed=False)
    _, first, inverse = np.unique(labels, return_index=True, return_inverse=True)
    order = np.argsort(np.argsort(first))  # renumber by first appearance
    return order[inverse.ravel()]


def estimated_error(X_nodes: np.ndarray, loo: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(p, m) estimated interpolation error at ``X`` from the nodes' leave-one-out errors ``loo`` (B, m).

    Leaving node j out opens a hole of radius h_j (its distance to the nearest
    other node); its leave-one-out error e_j is the error of interpolating at
    h_j from the nearest node. At a distance d < h_j from node j the error is
    taken as e_j d / h_j (first order: the interpolant is exact at the node;
    for a smooth ratio the error grows as d^2, so this is an upper estimate);
    the two nearest nodes' estimates are weighted by inverse distance. A
    logged pose a fraction of a millimetre from an anchor (a second log with
    the robot's position noise) is then known to the anchor's accuracy.

    Example
    -------
    >>> Xn = np.array([[0.0], [1.0], [2.0]])
    >>> loo = np.array([[0.1], [0.2], [0.1]])
    >>> estimated_error(Xn, loo, np.array([[1.01], [1.5]])).round(4).tolist()
    [[0.003], [0.075]]
    """
    from scipy.spatial import cKDTree

    X_nodes, X = np.asarray(X_nodes, float), np.asarray(X, float)
    tree = cKDTree(X_nodes)
    h = tree.query(X_nodes, k=2)[0][:, 1] if len(X_nodes) > 1 else np.full(1, np.inf)
    d, j = tree.query(X, k=min(2, len(X_nodes)))
    d, j = d.reshape(len(X), -1), j.reshape(len(X), -1)
    near = np.minimum(1.0, d / np.maximum(h[j], 1e-12))[..., None] * loo[j]  # (p, k, m)
    w = 1.0 / np.maximum(d, 1e-9)
    return np.einsum("pk,pkm->pm", w, near) / w.sum(axis=1, keepdims=True)


def _spread(candidates: np.ndarray, weight: np.ndarray, passes: list, k: int) -> np.ndarray:
    """About ``k`` of ``candidates``, both ends of each pass, spread in the cumulative ``1 + weight`` along the pass."""
    from electrosense.validation.diagnosis.multifidelity import choose_bem_poses

    chosen = choose_bem_poses(weight, passes, k)
    return np.intersect1d(chosen, candidates)


def anchored_baseline(obs, noise: float, target_factor: float = 1.0 / 3.0, psm_model=None, bem_options=None,
                      store: AnchorStore | None = None, first_fraction: float = 0.2, step_fraction: float = 0.1,
                      max_bem_s: float = MAX_BEM_SECONDS, check_discretisation: bool = True,
                      pose_reference=None, progress=None) -> AnchoredBaseline:
    """The BEM at an adaptive set of logged poses, interpolated (module doc), until its estimated error is below
    ``target_factor * noise`` (module doc); K at the observations' conductivity.

    ``pose_reference`` (``(poses, tank, objects) -> K``, the diagnosis's effect model), optional: then the BEM's
    own change of K with pose is computed too (:mod:`.pose_gradient`, cached with the anchors), as
    ``pose_gradient`` of the result.
    """
    from electrosense.validation.diagnosis.forward import effect_objects
    from electrosense.validation.diagnosis.where import place_labels
    from electrosense.validation.simulation.models import calibrated_psm, pose_evaluator

    t0 = time.perf_counter()
    say = progress or (lambda s: None)
    sensor, tank, objects = obs.sensor, obs.tank, tuple(obs.objects)
    bem_options = default_bem_options(sensor, bem_options)
    store = store or AnchorStore(sensor, tank, objects, bem_options)
    P, n = obs.n_poses, sensor.n_electrodes
    target = max(target_factor * noise, 1e-7)
    model = psm_model if psm_model is not None else calibrated_psm(sensor)
    ok = psm_usable(model, obs.poses, tank)
    if ok.mean() < 0.5:  # its spheres do not fit the tank (or the calibration degenerated): spheres at the electrodes
        from electrosense.validation.diagnosis.forward import geometric_psm

        geometric = geometric_psm(sensor, model)
        if psm_usable(geometric, obs.poses, tank).sum() > ok.sum():
            model = geometric
            ok = psm_usable(model, obs.poses, tank)
            say("the calibrated PSM does not fit these poses; its radii with the spheres at the electrodes are used")
    F = pose_features(sensor, obs.poses)
    group = same_pose_groups(F)
    first_of = np.full(group.max() + 1, P)
    np.minimum.at(first_of, group, np.arange(P))
    entry = store.load()
    cached_poses = np.zeros((0, 4)) if entry is None else entry["poses"]
    cached_K = np.zeros((0, n, n)) if entry is None else entry["K_unit"]
    from electrosense.meshes.scene_mesh import trajectory_focus_m

    focus_new = trajectory_focus_m(sensor, obs.poses)
    # reuse the stored tank mesh if it was graded towards this log's trajectory (within a few mm)
    covered = False
    if entry is not None and len(entry.get("focus_m", [])):
        from scipy.spatial import cKDTree

        dist, _ = cKDTree(entry["focus_m"]).query(focus_new)
        covered = bool(np.max(dist) < 0.005)
    if not covered:
        cached_poses, cached_K = np.zeros((0, 4)), np.zeros((0, n, n))
    focus = entry["focus_m"] if covered else focus_new
    # a cached BEM pose within 0.05 mm of a logged one: that sample is exact
    exact = np.full(P, -1)
    if len(cached_poses):
        from scipy.spatial import cKDTree

        d, j = cKDTree(pose_features(sensor, cached_poses)).query(F)
        exact[d < 5e-5] = j[d < 5e-5]
    K_bem = np.full((P, n, n), np.nan)
    K_bem[exact >= 0] = cached_K[exact[exact >= 0]]
    # the shape derivatives at the BEM poses (:mod:`electrosense.bem.shape_derivative`): of the walls (for the
    # wall effects) and, with nothing else in the tank, of the sensor's pose (for the pose effects)
    box = isinstance(tank, Tank)   # a cylindrical tank's regions are others: its derivatives are not asked for
    derivative_shapes = {"dK_dwall_S_per_m": (len(TANK_REGIONS), n, n)} if box else {}
    if box and not objects:
        derivative_shapes["dK_dpose"] = (3, n, n)
    regions_ok = entry is not None and tuple(str(r) for r in entry.get("wall_regions", ())) == TANK_REGIONS
    derivatives, cached_derivatives = {}, {}
    for key, shape in derivative_shapes.items():
        derivatives[key] = np.full((P,) + shape, np.nan)
        stored = entry.get(key) if covered and regions_ok else None
        cached_derivatives[key] = stored if stored is not None else np.full((len(cached_poses),) + shape, np.nan)
        derivatives[key][exact >= 0] = cached_derivatives[key][exact[exact >= 0]]
    carried = _carry_cached(sensor, obs.poses, F, exact, cached_poses, cached_K, cached_derivatives, K_bem, derivatives)
    # the PSM at the logged poses it accepts and at the cached anchors off them, in one evaluation: one image
    # series for all, so that the ratio BEM / PSM is the same function at every node (two evaluations settle
    # their image series on different pose sets and differ by up to a few 1e-3 near the walls)
    cached_usable = psm_usable(model, cached_poses, tank) if len(cached_poses) else np.zeros(0, bool)
    # cached anchors off this log's poses; one carried to a sample is that sample (kept as a node beside it, a
    # fraction of a millimetre away, each would predict the other in the leave-one-out test: the error estimate
    # there would be the carry's, not the interpolation's)
    off_log = ~np.isin(np.arange(len(cached_poses)), np.concatenate([exact[exact >= 0], carried]))
    extra = off_log & cached_usable
    K_psm = np.full((P, n, n), np.nan)
    psm_poses = np.vstack([obs.poses[ok], cached_poses[extra]])
    K_psm_all = np.zeros((0, n, n))
    if len(psm_poses):
        # the balls in the PSM (effect_objects); a pole or a box is in the BEM alone, its change in the ratio
        ev = pose_evaluator("psm", sensor, tank, 1.0, effect_objects(objects), psm_model=model, poses=psm_poses)
        K_psm_all = ev.conductance(psm_poses).K_S
        K_psm[ok] = K_psm_all[: int(ok.sum())]
    sweep = None
    n_new = 0
    new_poses, new_K, new_derivatives = [], [], {}
    bem_seconds = [0.0, 0]  # CPU seconds of BEM poses, count (for the budget: the same answer on a busy machine)

    def get_sweep():
        nonlocal sweep
        if sweep is None:
            from electrosense.bem import PoseSweep

            # its tank mesh serves every later log of this path (the BEM checks of pose offsets and contact
            # impedances solve on it): its factors are kept on disk with the sensor's
            sweep = PoseSweep(sensor, tank, objects, sigma_S_per_m=1.0, focus_m=focus,
                              **{"cache_environment": True, **bem_options})
        return sweep

    def run_bem(idx):
        nonlocal n_new
        idx = np.asarray([i for i in idx if not np.isfinite(K_bem[i, 0, 0])], int)
        if not len(idx):
            return
        get_sweep()
        groups = np.unique(group[idx])  # one solve per distinct pose, shared by every sample at it
        rep = first_of[groups]
        say(f"BEM at {len(rep)} poses" + (f" ({len(idx)} samples)" if len(idx) > len(rep) else ""))
        t_bem = time.process_time()
        g = sweep.conductance(obs.poses[rep], wall_derivatives=bool(derivatives))
        K = g.K_S
        bem_seconds[0] += time.process_time() - t_bem
        bem_seconds[1] += len(rep)
        members = np.flatnonzero(np.isin(group, groups) & ~np.isfinite(K_bem[:, 0, 0]))
        K_bem[members] = K[np.searchsorted(groups, group[members])]
        for key, values in derivatives.items():
            got = g.info.get(key, np.full((len(rep),) + values.shape[1:], np.nan))
            values[members] = got[np.searchsorted(groups, group[members])]
            new_derivatives.setdefault(key, []).append(got)
        n_new += len(rep)
        new_poses.append(obs.poses[rep])
        new_K.append(K)

    rec = _receiver_entries(sensor)
    passes = obs.pass_indices()
    # the free-space K (pose independent): the reference of the "free" base, and of the tank's effect
    K_free = pose_evaluator("psm", sensor, None, 1.0, (), psm_model=model).conductance(obs.poses[:1]).K_S[0]
    free = receiver_currents(K_free[None], obs.emitter)[0]
    tank_effect = np.ones(P)  # where the tank matters most: the PSM's own tank effect (unit where it refuses)
    if ok.any():
        tank_effect[ok] = np.max(np.abs(receiver_currents(K_psm[ok], obs.emitter) / free - 1), axis=1)
    # the bases, K_ref: what the BEM's ratio is interpolated against, at the samples, the samples it serves, the
    # cached anchors it uses and K_ref there
    K_psm_cached = np.full((len(cached_poses), n, n), np.nan)
    K_psm_cached[extra] = K_psm_all[int(ok.sum()):]
    bases = {"psm": (K_psm, ok, extra, K_psm_cached),
             "free": (np.broadcast_to(K_free, (P, n, n)), np.ones(P, bool), off_log,
                      np.broadcast_to(K_free, (len(cached_poses), n, n)))}
    rounds = []
    stopped = ""
    labels = place_labels(obs)
    error = np.zeros((P, n - 1))
    loo_all = np.zeros((0, n - 1))
    psm_vs_bem = np.zeros((0, n - 1))
    L = np.zeros((P, n * (n - 1) // 2))
    base = "psm"
    first = not off_log.any() and not (exact >= 0).any()   # nothing cached: a first spread of anchors
    if first:
        run_bem(np.flatnonzero(~ok))   # where the PSM refuses (near the walls: where the tank matters most)
    while True:
        have = np.isfinite(K_bem[:, 0, 0])
        if first:
            first = False
            k = max(8, int(np.ceil(first_fraction * ok.sum())))
            if len(_distinct(np.flatnonzero(have & ok), group)) < k and not have[ok].all():
                ok_passes = [p[ok[p]] for p in passes if ok[p].any()]
                run_bem(_spread(np.flatnonzero(ok), tank_effect, ok_passes, k))
                continue
        fits = {name: _fit_base(K_bem, F, group, have, *spec, cached_K, cached_poses, cached_usable, ok, sensor, rec)
                for name, spec in bases.items()}
        fits = {name: fit for name, fit in fits.items() if fit is not None}
        if not fits:
            run_bem(np.flatnonzero(~have))
            continue
        # the base whose interpolation predicts the BEM better at the PSM-usable anchors (leave-one-out)
        base = min(fits, key=lambda name: fits[name]["loo_usable_rms"])
        fit = fits[base]
        usable = bases[base][1]
        if (~have & ~usable).any():   # samples this base cannot serve: the BEM covers
            run_bem(np.flatnonzero(~have & ~usable))
            continue
        todo = np.flatnonzero(~have)
        loo = fit["loo"]
        loo_all = loo[fit["from_log"]]
        if "psm" in fits:
            psm_vs_bem = np.abs(np.expm1(fits["psm"]["L"][fits["psm"]["from_log"]][:, rec]))
        error = np.zeros((P, n - 1))
        if len(todo):
            L[todo] = fit["interp"](F[todo])
            error[todo] = estimated_error(fit["X"], loo, F[todo])
        region_rms = {g: float(np.sqrt(np.mean(error[labels == g] ** 2))) for g in dict.fromkeys(labels.tolist())}
        total = float(np.sqrt(np.mean(error**2)))
        worst_region = max(region_rms.values()) if region_rms else 0.0
        rounds.append({"bem_poses": int(have.sum()), "rms_error": total, "worst_region_rms": worst_region,
                       "base": base, **{f"loo_rms_{k}": v["loo_usable_rms"] for k, v in fits.items()}})
        say(f"baseline error {100 * total:.4f} % RMS (worst region {100 * worst_region:.4f} %) with the BEM at "
            f"{int(have.sum())} of {P} poses, ratio to the {base} base; target {100 * target:.4f} %")
        if (total <= target and worst_region <= target) or not len(todo):
            break
        k = max(4, int(np.ceil(step_fraction * P)))
        per_pose = bem_seconds[0] / max(bem_seconds[1], 1)
        if bem_seconds[0] + k * per_pose > max_bem_s:
            stopped = (f"time budget: {bem_seconds[0]:.0f} s CPU of BEM poses spent, {max_bem_s:.0f} s allowed; the "
                       "estimated error is reported as it stands")
            say(stopped)
            break
        by_error = todo[np.argsort(np.max(error[todo], axis=1))[::-1]]
        distinct = np.sort(np.unique(group[by_error], return_index=True)[1])
        run_bem(by_error[distinct[:k]])
    have = np.isfinite(K_bem[:, 0, 0])
    K = np.where(have[:, None, None], K_bem, 0.0)
    fill = ~have
    if fill.any():
        K[fill] = _apply_log_ratio(bases[base][0][fill], L[fill], sensor.emitter)
    # the BEM's own discretisation: a finer mesh at a few anchor poses, extrapolated (cached with the anchors)
    check = {k[6:]: entry[k] for k in (entry or {}) if k.startswith("check_")} if covered else {}
    if check_discretisation and not check and len(np.flatnonzero(have)):
        try:
            check = _discretisation_check(sensor, tank, objects, bem_options, focus, obs.poses, K_bem,
                                          have & (np.arange(P) == first_of[group]), tank_effect, rec, say)
        except Exception as exc:  # the estimate is optional; say so in the budget
            say(f"BEM discretisation not estimated ({type(exc).__name__}: {exc})")
            check = {}
    grad, grad_entry = None, {}
    if pose_reference is not None and "dK_dpose" in derivatives and _every_pass_has(derivatives["dK_dpose"], passes):
        from electrosense.validation.diagnosis.pose_gradient import pose_gradient_from_derivatives

        ref = lambda p: pose_reference(p, tank, objects)  # noqa: E731
        grad = pose_gradient_from_derivatives(sensor, obs.poses, passes, derivatives["dK_dpose"], K, ref)
    elif pose_reference is not None:
        try:
            grad, grad_entry = _pose_gradient(obs, entry if covered else None, get_sweep, passes, say,
                                              pose_reference, K_bem)
        except Exception as exc:  # the pose effects fall back on the effect model; say so
            say(f"BEM pose gradient not computed ({type(exc).__name__}: {exc}); pose effects through the PSM")
    bem_error = None
    if check:
        from scipy.spatial import cKDTree

        _, j = cKDTree(pose_features(sensor, check["poses"])).query(F)
        bem_error = check["error"][j]
    if new_poses or (check and "check_poses" not in (entry or {})) or (grad_entry and "grad_nodes" not in (entry or {})):
        entry_poses = np.vstack([cached_poses] + new_poses)
        entry_K = np.vstack([cached_K] + new_K)
        saved = {"poses": entry_poses, "K_unit": entry_K, "focus_m": focus}
        for key in derivatives:
            saved[key] = np.concatenate([cached_derivatives[key]] + new_derivatives.get(key, []))
        if derivatives:
            saved["wall_regions"] = np.array(TANK_REGIONS)
        saved.update({f"check_{k}": v for k, v in check.items()})
        saved.update({f"grad_{k}": v for k, v in grad_entry.items()})
        store.save(saved)
    anchors = np.flatnonzero(have)
    return AnchoredBaseline(
        K=K * obs.sigma_S_per_m, error=error, anchors=anchors, refused=np.flatnonzero(~ok), n_bem_new=n_new,
        n_cached=int(np.sum(exact >= 0)) + len(carried) + int(bases[base][2].sum()), target=target, rounds=rounds, base=base,
        psm_vs_bem_rms=float(np.sqrt(np.mean(psm_vs_bem**2))) if psm_vs_bem.size else float("nan"),
        loo_rms=float(np.sqrt(np.mean(loo_all**2))) if loo_all.size else 0.0,
        seconds=time.perf_counter() - t0, bem_error=bem_error, stopped=stopped, pose_gradient=grad,
        wall_derivatives=(derivatives["dK_dwall_S_per_m"] * obs.sigma_S_per_m if "dK_dwall_S_per_m" in derivatives
                          else None),
        wall_regions=TANK_REGIONS if derivatives else (), focus_m=focus, bem_sweep=get_sweep,
    )


def _carry_cached(sensor, poses, F, exact, cached_poses, cached_K, cached_derivatives, K_bem,
                  derivatives) -> np.ndarray:
    """Carry the cached BEM poses within :data:`DERIVATIVE_REUSE_M` of a sample to it, by their own derivatives.

    Another log of the same path logs the same nominal poses with the robot's own position noise (a tenth of a
    millimetre), where the tank's effect changes by up to a percent per millimetre near a wall: an interpolant
    through the other log's poses would hand that difference on as noise. A cached pose that holds the BEM's
    pose and wall derivatives is carried to the sample to first order (x, y and yaw from the pose derivatives,
    z from the floor's and the surface's: the sensor rising is the floor moving away and the surface coming
    closer), the error second order in the offset; the sample then counts as a BEM pose, with those
    derivatives. Fills ``K_bem`` and ``derivatives`` in place; returns, for each sample carried, the index of the
    cached pose it was carried from.
    """
    from scipy.spatial import cKDTree

    from electrosense.validation.diagnosis.pose_gradient import apply_pair_log

    none = np.zeros(0, int)
    if not len(cached_poses) or "dK_dpose" not in derivatives or "dK_dwall_S_per_m" not in derivatives:
        return none
    dP, dW = cached_derivatives["dK_dpose"], cached_derivatives["dK_dwall_S_per_m"]
    known = np.all(np.isfinite(dP.reshape(len(dP), -1)), axis=1) & np.all(np.isfinite(dW.reshape(len(dW), -1)), axis=1)
    if not known.any():
        return none
    d, j = cKDTree(pose_features(sensor, cached_poses[known])).query(F)
    j = np.flatnonzero(known)[j]
    take = np.flatnonzero((exact < 0) & (d < DERIVATIVE_REUSE_M))
    if not len(take):
        return none
    src = j[take]
    n = cached_K.shape[-1]
    iu = np.triu_indices(n, 1)
    up = TANK_REGIONS.index("floor"), TANK_REGIONS.index("free_surface")
    dK = np.stack([dP[src, 0], dP[src, 1], dW[src, up[0]] - dW[src, up[1]], dP[src, 2]], axis=1)   # x, y, z, yaw
    G = dK[..., iu[0], iu[1]] / cached_K[src][:, None, iu[0], iu[1]]
    delta = np.asarray(poses, float)[take] - cached_poses[src]
    delta[:, 3] = np.angle(np.exp(1j * delta[:, 3]))
    K_bem[take] = apply_pair_log(cached_K[src], np.einsum("pk,pkq->pq", delta, G))
    for key, values in derivatives.items():
        values[take] = cached_derivatives[key][src]
    return src


def _every_pass_has(values: np.ndarray, passes: list, at_least: int = 2) -> bool:
    """Whether every pass holds ``at_least`` samples where ``values`` (P, ...) is finite."""
    known = np.all(np.isfinite(values.reshape(len(values), -1)), axis=1)
    return all(known[np.asarray(p)].sum() >= at_least for p in passes)


#: gradient nodes: a tenth of the log's samples, at least five a pass (both ends and three between)
GRADIENT_NODE_FRACTION = 0.1
GRADIENT_NODES_PER_PASS = 5


def _pose_gradient(obs, entry, get_sweep, passes, say, reference, K_bem):
    """The BEM's d log K / d(x, y, yaw) at the logged poses (:mod:`.pose_gradient`), from the stored nodes of
    ``entry`` when they serve this log (the same tank mesh), else from new ones; (gradient, what to store)."""
    from electrosense.validation.diagnosis.multifidelity import choose_bem_poses
    from electrosense.validation.diagnosis.pose_gradient import PoseGradient, log_derivatives, pose_gradient, stencil

    n = obs.sensor.n_electrodes
    pairs = n * (n - 1) // 2
    if obs.tank is None and not len(obs.objects):  # unbounded water, nothing in it: K does not depend on pose
        zero = np.zeros((obs.n_poses, 3, pairs))
        return PoseGradient(zero, zero.copy(), np.zeros((0, 4)), np.zeros((0, 3, pairs))), {}
    cached = None
    if entry is not None and "grad_nodes" in entry:
        cached = {"nodes": entry["grad_nodes"], "G": entry["grad_G"], "H": entry["grad_H"]}
    ref = lambda p: reference(p, obs.tank, tuple(obs.objects))  # noqa: E731
    # nodes dense where the effect model's gradient changes fastest along the pass
    G_ref, _ = log_derivatives(ref(stencil(obs.poses).reshape(-1, 4)).reshape(obs.n_poses, 7, n, n))
    k = max(GRADIENT_NODES_PER_PASS * len(passes), int(np.ceil(GRADIENT_NODE_FRACTION * obs.n_poses)))
    node_idx = choose_bem_poses(np.abs(G_ref).max(axis=(1, 2)), passes, k)
    have = np.flatnonzero(np.isfinite(K_bem[:, 0, 0]))
    if len(have):   # each node moved to the nearest anchor of its pass: the BEM there is known
        label = np.empty(obs.n_poses, int)
        for j, idx in enumerate(passes):
            label[idx] = j
        node_idx = np.unique([min((a for a in have if label[a] == label[i]), key=lambda a: abs(a - i), default=i)
                              for i in node_idx])
    grad, store = pose_gradient(obs.sensor, obs.poses, passes, lambda p: get_sweep().conductance(p).K_S, node_idx,
                                ref, cached, K_known=K_bem)
    if store:
        say(f"BEM pose gradient at {len(grad.nodes)} poses (6 or 7 solves each), {grad.seconds:.1f} s")
    return grad, store
def _distinct(idx: np.ndarray, group: np.ndarray) -> np.ndarray:
    """``idx`` less the samples at a pose already in it (one per distinct pose, in order)."""
    return idx[np.sort(np.unique(group[idx], return_index=True)[1])]


def _fit_base(K_bem, F, group, have, K_ref, usable, cached_off, K_ref_cached, cached_K, cached_poses, cached_usable,
              psm_ok, sensor, rec) -> dict | None:
    """The RBF interpolant of log(K_bem / K_ref) over the BEM anchors a base can use (this log's and the cached
    ones off its poses), its leave-one-out errors, and their RMS at the anchors where the PSM is usable (the
    nodes every base has, on which the bases are compared)."""
    nodes = _distinct(np.flatnonzero(have & usable), group)
    X = [F[nodes]]
    Lv = [_offdiag_log_ratio(K_bem[nodes], K_ref[nodes], sensor.emitter)]
    on_usable = [psm_ok[nodes]]
    if cached_off.any():
        X.append(pose_features(sensor, cached_poses[cached_off]))
        Lv.append(_offdiag_log_ratio(cached_K[cached_off], K_ref_cached[cached_off], sensor.emitter))
        on_usable.append(cached_usable[cached_off])
    X, Lv, on_usable = np.vstack(X), np.vstack(Lv), np.concatenate(on_usable)
    from_log = np.arange(len(X)) < len(nodes)
    if not len(X):
        return None
    # nodes closer than NODE_MERGE_M (an earlier log's anchor beside this log's, a fraction of a millimetre
    # apart with the robot's position noise) carry the same information and make the interpolation
    # matrix, and the leave-one-out errors from its inverse, meaningless: keep the first (this log's)
    keep = np.sort(np.unique(same_pose_groups(X, NODE_MERGE_M), return_index=True)[1])
    X, Lv, on_usable, from_log = X[keep], Lv[keep], on_usable[keep], from_log[keep]
    interp = RBFInterpolant(X, Lv, min_trend_spread_m=TREND_MIN_SPREAD_M)
    loo = np.abs(np.expm1(interp.leave_one_out[:, rec]))  # (B, m) relative error of receiver currents
    at = loo[on_usable]
    return {"X": X, "L": Lv, "interp": interp, "loo": loo, "from_log": from_log,
            "loo_usable_rms": float(np.sqrt(np.mean(at**2))) if at.size else np.inf}


#: the finer mesh of the discretisation check, in units of the anchors' (sensor edge, tank edge)
CHECK_REFINEMENT = 1.5


def _discretisation_check(sensor, tank, objects, bem_options, focus, poses, K_bem, have, tank_effect, rec, say,
                          n_check: int = 4) -> dict:
    """The anchors' own discretisation error, measured: the BEM at ``n_check`` anchor poses (strongest, median
    and weakest tank effect) on a mesh :data:`CHECK_REFINEMENT` times finer (sensor and tank), extrapolated.

    With an error ``C h^p`` the anchors' error is ``|K_fine / K - 1| q^p / (q^p - 1)`` (q the refinement);
    ``p = 1`` is taken (the electrode edges' r^-1/2 singularity in the tank's graded mesh converges at about
    first order; a faster convergence makes this an upper estimate): three times the change to the finer mesh.
    """
    from electrosense.bem import PoseSweep
    from electrosense.meshes.scene_mesh import default_tank_edge_length_m

    idx = np.flatnonzero(have)
    order = idx[np.argsort(tank_effect[idx])]
    pick = np.unique(order[np.round(np.linspace(0, len(order) - 1, min(n_check, len(order)))).astype(int)])
    opts = dict(bem_options)
    q = CHECK_REFINEMENT
    opts["edge_length_m"] = opts["edge_length_m"] / q
    opts["tank_edge_length_m"] = (opts.get("tank_edge_length_m") or default_tank_edge_length_m(sensor)) / q
    say(f"BEM discretisation check at {len(pick)} poses (mesh {q}x finer)")
    fine = PoseSweep(sensor, tank, objects, sigma_S_per_m=1.0, focus_m=focus, **opts).conductance(poses[pick]).K_S
    e = sensor.emitter - 1
    r = [k for k in range(sensor.n_electrodes) if k != e]
    err = np.abs(fine[:, r, e] / K_bem[pick][:, r, e] - 1.0) * q / (q - 1.0)
    return {"poses": poses[pick], "error": err}
