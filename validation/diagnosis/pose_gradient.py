"""The BEM's own change of K with the sensor's pose: d log K / d(x, y, yaw) at every logged pose.

A robot-frame offset of a few millimetres, or a heading off by a few
hundredths of a radian, moves every sample by a fraction of the noise; over a
log of hundreds of samples that is detectable, but only through a model that
knows how K changes with pose as the BEM does (the PSM's pose dependence is
off by tens of percent near a wall). Here:

1. at a few *nodes* among the logged poses (both ends of every pass, spread
   where the tank's effect changes fastest) the BEM is solved at the pose and
   at the six poses one step away along x, y and yaw (:data:`POSE_STEPS`);
2. central differences give the gradient ``G`` and the diagonal second
   derivatives ``H`` of the logarithm of every off-diagonal entry of K;
3. their departures from the effect model's gradient (the geometric PSM
   with Kelvin spheres, by the same differences at every logged pose) are
   interpolated along each pass (monotone cubic in the distance travelled),
   with their leave-one-out errors: at a node the gradient is the BEM's,
   between nodes the effect model's shape corrected by the BEM (on a random
   5-electrode sensor in a box tank: the effect model's gradient is 5 % off
   the BEM's, corrected at 13 nodes of 45 poses 1.2 %, where interpolating
   the BEM's gradient alone is 30 % off: it changes as fast as the wall's
   effect, the correction does not);
4. a moved pose is predicted by a second-order Taylor step from the logged one
   (:meth:`PoseGradient.moved`): ``log K(p + d) = log K(p) + G d + H d^2 / 2``,
   the zero row sums restored. At the logged pose it *is* the baseline.

In unbounded water with no object K does not depend on pose: ``G = H = 0``.

Example
-------
>>> import numpy as np
>>> poses = np.array([[0.0, 0.0, 0.0, 0.0]])
>>> stencil(poses).shape
(1, 7, 4)
>>> stencil(poses)[0, 1].tolist(), stencil(poses)[0, 6].tolist()
([0.001, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, -0.01])
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["POSE_STEPS", "stencil", "log_derivatives", "PoseGradient", "pose_gradient",
           "pose_gradient_from_derivatives", "arc_length", "along_passes", "pair_log", "apply_pair_log"]

#: finite-difference steps along x (m), y (m) and yaw (rad): small against the distance to a wall (>= 1.5 cm),
#: large against the BEM's quadrature noise
POSE_STEPS = np.array([1e-3, 1e-3, 1e-2])

#: columns of the pose (x, y, z, yaw) the gradient is taken along
POSE_AXES = (0, 1, 3)


def stencil(poses: np.ndarray, steps: np.ndarray = POSE_STEPS) -> np.ndarray:
    """(p, 7, 4): each pose, then +-step along x, +-step along y, +-step along yaw."""
    poses = np.asarray(poses, float).reshape(-1, 4)
    out = np.repeat(poses[:, None, :], 7, axis=1)
    for k, (axis, h) in enumerate(zip(POSE_AXES, steps)):
        out[:, 1 + 2 * k, axis] += h
        out[:, 2 + 2 * k, axis] -= h
    return out


def pair_log(K: np.ndarray) -> np.ndarray:
    """(..., n (n - 1) / 2): log of the magnitude of every off-diagonal entry (upper triangle) of K (..., n, n)."""
    n = K.shape[-1]
    iu = np.triu_indices(n, 1)
    return np.log(np.abs(K[..., iu[0], iu[1]]))


def apply_pair_log(K: np.ndarray, dL: np.ndarray) -> np.ndarray:
    """K (p, n, n) with both entries of every pair scaled by exp(dL) (p, pairs), zero row sums restored.

    The two entries of a pair keep their own values: a BEM's K is symmetric only to its discretisation (a few
    1e-4), and a step of zero must give back the K it was given.

    >>> K = np.array([[[-2.0, 1.0, 1.0], [1.001, -2.0, 0.999], [1.0, 1.0, -2.0]]])
    >>> bool(np.allclose(apply_pair_log(K, np.zeros((1, 3)))[0, 1], [1.001, -2.0, 0.999]))
    True
    """
    n = K.shape[-1]
    iu = np.triu_indices(n, 1)
    out = np.array(K, float)
    out[:, iu[0], iu[1]] *= np.exp(dL)
    out[:, iu[1], iu[0]] *= np.exp(dL)
    off = out * (1 - np.eye(n))
    return off - np.eye(n) * off.sum(axis=-1, keepdims=True)


def log_derivatives(K_stencil: np.ndarray, steps: np.ndarray = POSE_STEPS) -> tuple[np.ndarray, np.ndarray]:
    """Gradient and diagonal second derivatives (p, 3, pairs) of log K from the stencil's K (p, 7, n, n).

    Example
    -------
    >>> K = np.zeros((1, 7, 2, 2))
    >>> v = np.exp(np.array([0.0, 1e-3, -1e-3, 0, 0, 0, 0]))  # log K = x / m along x
    >>> K[0, :, 0, 1] = K[0, :, 1, 0] = v
    >>> G, H = log_derivatives(K)
    >>> round(float(G[0, 0, 0]), 6), round(float(H[0, 0, 0]), 6)
    (1.0, 0.0)
    """
    L = pair_log(np.asarray(K_stencil, float))  # (p, 7, pairs)
    h = np.asarray(steps, float)[None, :, None]
    plus, minus = L[:, 1::2], L[:, 2::2]
    G = (plus - minus) / (2 * h)
    H = (plus - 2 * L[:, :1] + minus) / h**2
    return G, H


@dataclass
class PoseGradient:
    """d log K / d(x, y, yaw) and the diagonal second derivatives at every logged pose, and their accuracy.

    ``G``, ``H``: (P, 3, pairs); ``nodes``: (B, 4) the poses where the BEM gave them; ``loo_G`` (B, 3, pairs)
    their leave-one-out interpolation errors (zero when every logged pose is a node).
    """

    G: np.ndarray
    H: np.ndarray
    nodes: np.ndarray
    loo_G: np.ndarray
    seconds: float = 0.0
    reference: str = "none"  # the fast model whose gradient the BEM's corrects
    how: str = ("the BEM at 7 poses around each node (central differences, steps 1 mm and 0.01 rad), the departure "
                "from the effect model's gradient interpolated along each pass")

    def log_change(self, idx: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """(p, pairs): the change of log K at samples ``idx`` for pose steps ``delta`` (p, 3: dx, dy, dyaw)."""
        d = np.asarray(delta, float)
        return (np.einsum("pk,pkq->pq", d, self.G[idx]) + 0.5 * np.einsum("pk,pkq->pq", d**2, self.H[idx]))

    def moved(self, K: np.ndarray, idx: np.ndarray, poses_from: np.ndarray, poses_to: np.ndarray) -> np.ndarray:
        """K (p, n, n) at samples ``idx`` carried from ``poses_from`` to ``poses_to`` (p, 4; same z)."""
        d = np.asarray(poses_to, float)[:, POSE_AXES] - np.asarray(poses_from, float)[:, POSE_AXES]
        d[:, 2] = np.angle(np.exp(1j * d[:, 2]))
        return apply_pair_log(K, self.log_change(np.asarray(idx), d))

    def error_per_step(self, rec: list) -> dict:
        """RMS leave-one-out error of the receivers' log-change for a 1 mm step in x and y and 0.01 rad in yaw
        (relative current), beside the change itself: how far the interpolated gradient is from the BEM's."""
        unit = np.array([1e-3, 1e-3, 1e-2])[None, :, None]
        err = np.abs(self.loo_G[:, :, rec]) * unit
        size = np.abs(self.G[:, :, rec]) * unit
        rms = lambda x: float(np.sqrt(np.mean(x**2))) if x.size else 0.0  # noqa: E731
        return {"loo_rms": {a: rms(err[:, k]) for k, a in enumerate(("x_1mm", "y_1mm", "yaw_0.01rad"))},
                "change_rms": {a: rms(size[:, k]) for k, a in enumerate(("x_1mm", "y_1mm", "yaw_0.01rad"))},
                "nodes": int(len(self.nodes))}


def arc_length(sensor, poses: np.ndarray, passes: list) -> np.ndarray:
    """(P,) the distance travelled along each pass (m, both tips' positions), from 0 at its first sample."""
    from electrosense.validation.diagnosis.anchored import pose_features

    F = pose_features(sensor, poses)
    s = np.zeros(len(poses))
    for idx in passes:
        idx = np.asarray(idx)
        step = np.linalg.norm(np.diff(F[idx], axis=0), axis=1)
        s[idx] = np.concatenate([[0.0], np.cumsum(step)])
    return s


def along_passes(values: np.ndarray, node_sample: np.ndarray, s: np.ndarray, passes: list):
    """``values`` (B, ...) known at the nodes (their nearest samples ``node_sample``) interpolated to every sample
    along its pass (monotone cubic in the arc length ``s``; constant beyond the end nodes; zero on a pass with
    no node), and each node's leave-one-out error (B, ...; the node's own value where it cannot be left out)."""
    from scipy.interpolate import PchipInterpolator

    values = np.asarray(values, float)
    out = np.zeros((len(s),) + values.shape[1:])
    loo = np.abs(values).copy()

    def interp(at, x, v):
        if len(x) == 1:
            return np.broadcast_to(v[0], (len(at),) + v.shape[1:])
        return PchipInterpolator(x, v, axis=0, extrapolate=False)(np.clip(at, x[0], x[-1]))

    for idx in passes:
        idx = np.asarray(idx)
        mine = np.flatnonzero(np.isin(node_sample, idx))
        if not len(mine):
            continue
        x = s[node_sample[mine]]
        order = np.argsort(x)
        mine, x = mine[order], x[order]
        x, first = np.unique(x, return_index=True)   # two nodes at one place: keep one
        mine = mine[first]
        out[idx] = interp(s[idx], x, values[mine])
        for j in range(1, len(mine) - 1):   # interior nodes: predicted from the others
            keep = np.arange(len(mine)) != j
            loo[mine[j]] = np.abs(interp(x[j:j + 1], x[keep], values[mine[keep]])[0] - values[mine[j]])
    return out, loo


def pose_gradient_from_derivatives(sensor, poses: np.ndarray, passes: list, dK_dpose: np.ndarray, K: np.ndarray,
                                   reference, steps: np.ndarray = POSE_STEPS) -> PoseGradient:
    """The BEM's :class:`PoseGradient` from its exact first derivatives at the BEM poses.

    ``dK_dpose`` (P, 3, n, n): dK / d(x, y, yaw) where the BEM was solved (NaN elsewhere), from each solution's
    own shape derivative (:meth:`electrosense.bem.PoseSweep.conductance` with ``wall_derivatives``: no solve
    more), ``K`` (P, n, n) there. As in :func:`pose_gradient`, the departure of the BEM's gradient from the
    effect model's ``reference(poses) -> K`` is interpolated along each pass; the second derivatives are the
    effect model's.
    """
    import time

    t0 = time.perf_counter()
    poses = np.asarray(poses, float)
    P = len(poses)
    have = np.flatnonzero(np.all(np.isfinite(dK_dpose.reshape(P, -1)), axis=1))
    n = K.shape[-1]
    iu = np.triu_indices(n, 1)
    G_n = dK_dpose[have][..., iu[0], iu[1]] / K[have][:, None, iu[0], iu[1]]   # d log|K_ij|
    K_ref = reference(stencil(poses, steps).reshape(-1, 4))
    G_ref, H_ref = log_derivatives(K_ref.reshape(P, 7, *K_ref.shape[1:]), steps)
    s = arc_length(sensor, poses, passes)
    dG, loo = along_passes(G_n - G_ref[have], have, s, passes)
    return PoseGradient(G_ref + dG, H_ref, poses[have], loo, time.perf_counter() - t0, "effect model",
                        "the BEM's shape derivative at each BEM pose (the walls moving the other way, from that pose's "
                        "own solution), the departure from the effect model's gradient interpolated along each pass; "
                        "second derivatives the effect model's")


def pose_gradient(sensor, poses: np.ndarray, passes: list, solve, node_idx: np.ndarray, reference,
                  cached: dict | None = None, steps: np.ndarray = POSE_STEPS,
                  K_known: np.ndarray | None = None) -> tuple[PoseGradient, dict]:
    """The BEM's :class:`PoseGradient` at ``poses`` (P, 4) from nodes at the samples ``node_idx``.

    ``solve(poses (q, 4)) -> K (q, n, n)`` is the BEM, ``reference(poses) -> K`` a fast model of the same
    scene (the diagnosis's effect model): its gradient is taken at every sample, and the BEM's departure from
    it, known at the nodes, is interpolated along each pass (:func:`along_passes`). ``cached``
    (``{"nodes", "G", "H"}``) holds nodes computed before (reused when within 5 mm of this log's poses, none
    solved again). ``K_known`` (P, n, n; NaN where unknown): the BEM already solved at some samples (the
    anchors; at the same sigma as ``solve``): not solved again at a node. Returns the gradient and the nodes
    to store.
    """
    import time

    from scipy.spatial import cKDTree

    from electrosense.validation.diagnosis.anchored import pose_features

    t0 = time.perf_counter()
    poses = np.asarray(poses, float)
    P = len(poses)
    F = pose_features(sensor, poses)
    reuse = False
    if cached is not None and len(cached.get("nodes", ())):
        d, near = cKDTree(F).query(pose_features(sensor, cached["nodes"]))
        reuse = bool(np.all(d < 5e-3))
    if reuse:
        nodes, G_n, H_n, node_sample = cached["nodes"], cached["G"], cached["H"], near
    else:
        node_sample = np.asarray(node_idx, int)
        nodes = poses[node_sample]
        S = stencil(nodes, steps)
        known = np.zeros(len(nodes), bool) if K_known is None else np.isfinite(K_known[node_sample, 0, 0])
        todo = np.ones(S.shape[:2], bool)
        todo[known, 0] = False   # the BEM at the node itself is already known (an anchor)
        K_new = solve(S[todo])
        K = np.empty((len(nodes), 7) + K_new.shape[1:])
        K[todo] = K_new
        K[known, 0] = K_known[node_sample[known]]
        G_n, H_n = log_derivatives(K, steps)
    # the reference at every sample and at the nodes, in one evaluation (one image series for all)
    B = len(nodes)
    K_ref = reference(np.vstack([stencil(poses, steps), stencil(nodes, steps)]).reshape(-1, 4))
    G_ref, H_ref = log_derivatives(K_ref.reshape(P + B, 7, *K_ref.shape[1:]), steps)
    s = arc_length(sensor, poses, passes)
    dGH, loo = along_passes(np.concatenate([G_n - G_ref[P:], H_n - H_ref[P:]], axis=1), node_sample, s, passes)
    grad = PoseGradient(G_ref[:P] + dGH[:, :3], H_ref[:P] + dGH[:, 3:], nodes, loo[:, :3],
                        time.perf_counter() - t0, "effect model")
    return grad, ({} if reuse else {"nodes": nodes, "G": G_n, "H": H_n})
