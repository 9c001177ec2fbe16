"""Hot loop of the PSM: potential coefficients with images and objects, then K, pose by pose.

One compiled function evaluates a whole trajectory. It is written for any
float or complex dtype of the electrode positions, so that the Jacobian can
reuse it with a complex step (:mod:`psm.jacobian`). The mathematics is in
:mod:`psm.potential_coefficients`, :mod:`psm.images` and :mod:`psm.objects`;
this module only loops.
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["conductance_kernel"]


@njit(cache=True)
def _image_sum(xp, yp, zp, xq, yq, zq, signs, offsets, weights, k0, k1, zero):
    """sum_k w_k/|x_p - image_k(x_q)| over images k0..k1-1."""
    acc = zero
    for k in range(k0, k1):
        dx = xp - (signs[k, 0] * xq + offsets[k, 0])
        dy = yp - (signs[k, 1] * yq + offsets[k, 1])
        dz = zp - (signs[k, 2] * zq + offsets[k, 2])
        acc += weights[k] / np.sqrt(dx * dx + dy * dy + dz * dz)
    return acc


@njit(cache=True)
def conductance_kernel(X, R0, signs, offsets, weights, obj_pos, obj_coef, series_ohm, inv_4pi_sigma, receivers, emitter, K):
    """Fill K (P, n, n) for electrode centres X (P, n, 3) in the tank frame.

    Parameters
    ----------
    X : (P, n, 3) float or complex
        Sphere centres for each pose (tank frame, m).
    R0 : (n, n) float
        Free-space potential coefficients (1/m), pose-invariant.
    signs, offsets : (K, 3) float
        Image maps ``x -> signs * x + offsets``.
    weights : (K,) float
        Weight of each image (1, or 1/2 per axis on the outermost shell).
    obj_pos : (O, 3) float
        Object sphere centres (tank frame).
    obj_coef : (O,) float
        ``-chi b^3`` of each object (m^3).
    series_ohm : (n,) float
        Series (contact) resistance of each electrode, added to M's diagonal.
    inv_4pi_sigma : float
        ``1 / (4 pi sigma)`` (ohm m).
    receivers : (n-1,) int
        0-based receiver indices; ``emitter`` the 0-based emitter index.
    K : (P, n, n), same dtype as X
        Output.
    """
    n_pose, n, _ = X.shape
    m = n - 1
    n_img = signs.shape[0]
    n_obj = obj_pos.shape[0]
    zero = X[0, 0, 0] * 0.0
    M = np.empty((n, n), dtype=X.dtype)
    A = np.empty((m, m), dtype=X.dtype)
    Ainv = np.empty((m, m), dtype=X.dtype)
    G = np.empty((n, 3), dtype=X.dtype)
    for ip in range(n_pose):
        # potential coefficients R + dR (images), symmetric
        for p in range(n):
            for q in range(p, n):
                s = _image_sum(X[ip, p, 0], X[ip, p, 1], X[ip, p, 2], X[ip, q, 0], X[ip, q, 1], X[ip, q, 2],
                               signs, offsets, weights, 0, n_img, zero)
                M[p, q] = R0[p, q] + s
                M[q, p] = M[p, q]
        # objects: dR_pq += -chi b^3 grad_y G(y, c_p) . grad_y G(y, c_q) at y = object centre
        for o in range(n_obj):
            y0, y1, y2 = obj_pos[o, 0], obj_pos[o, 1], obj_pos[o, 2]
            for q in range(n):
                g0 = zero
                g1 = zero
                g2 = zero
                for k in range(-1, n_img):
                    if k < 0:
                        ix, iy, iz = X[ip, q, 0], X[ip, q, 1], X[ip, q, 2]
                    else:
                        ix = signs[k, 0] * X[ip, q, 0] + offsets[k, 0]
                        iy = signs[k, 1] * X[ip, q, 1] + offsets[k, 1]
                        iz = signs[k, 2] * X[ip, q, 2] + offsets[k, 2]
                    dx, dy, dz = y0 - ix, y1 - iy, y2 - iz
                    r2 = dx * dx + dy * dy + dz * dz
                    w = 1.0 / (r2 * np.sqrt(r2))
                    if k >= 0:
                        w *= weights[k]
                    g0 -= dx * w
                    g1 -= dy * w
                    g2 -= dz * w
                G[q, 0], G[q, 1], G[q, 2] = g0, g1, g2
            for p in range(n):
                for q in range(n):
                    M[p, q] += obj_coef[o] * (G[p, 0] * G[q, 0] + G[p, 1] * G[q, 1] + G[p, 2] * G[q, 2])
        # ohms, contact impedance in series
        for p in range(n):
            for q in range(n):
                M[p, q] *= inv_4pi_sigma
            M[p, p] += series_ohm[p]
        # A = P^T M P
        for a in range(m):
            ra = receivers[a]
            for b in range(m):
                rb = receivers[b]
                A[a, b] = M[ra, rb] - M[ra, emitter] - M[emitter, rb] + M[emitter, emitter]
                Ainv[a, b] = 1.0 if a == b else 0.0
        # Gauss-Jordan without pivoting (A is symmetric positive definite)
        for c in range(m):
            piv = 1.0 / A[c, c]
            for b in range(m):
                A[c, b] *= piv
                Ainv[c, b] *= piv
            for r in range(m):
                if r != c:
                    f = A[r, c]
                    for b in range(m):
                        A[r, b] -= f * A[c, b]
                        Ainv[r, b] -= f * Ainv[c, b]
        # K = P Ainv P^T
        tot = zero
        for a in range(m):
            ra = receivers[a]
            row = zero
            for b in range(m):
                K[ip, ra, receivers[b]] = Ainv[a, b]
                row += Ainv[a, b]
            K[ip, ra, emitter] = -row
            K[ip, emitter, ra] = -row
            tot += row
        K[ip, emitter, emitter] = tot
