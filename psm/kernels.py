"""Hot loop of the PSM: potential coefficients with images and objects, then K, pose by pose.

One compiled function evaluates a whole trajectory. It is written for any
float or complex dtype of the electrode positions, so that the Jacobian can
reuse it with a complex step (:mod:`electrosense.psm.jacobian`). The mathematics is in
:mod:`electrosense.psm.potential_coefficients`, :mod:`electrosense.psm.images` and :mod:`electrosense.psm.objects`;
this module only loops.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

__all__ = ["conductance_kernel", "multipole_image_kernel"]


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


@njit(cache=True, parallel=True)
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
    for ip in prange(n_pose):   # poses are independent: one thread each (numba's threads, NUMBA_NUM_THREADS)
        M = np.empty((n, n), dtype=X.dtype)
        A = np.empty((m, m), dtype=X.dtype)
        Ainv = np.empty((m, m), dtype=X.dtype)
        G = np.empty((n, 3), dtype=X.dtype)
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


@njit(cache=True)
def pose_derivative_kernel(X, positions, K, signs, offsets, weights, obj_pos, obj_coef, inv_4pi_sigma, dK):
    """Fill dK (P, 3, n, n) = dK / d(x, y, yaw) for every pose, analytically.

    With V = M I and K = P (P^T M P)^-1 P^T, ``dK = -K dM K``. Only the tank
    images and the objects make M depend on the pose (the free-space R and
    the contact term do not). A sphere centre moves with the pose as
    ``dX/dx = e_x``, ``dX/dy = e_y``, ``dX/dyaw = e_z x (X - position)``;
    an image ``sigma * X + o`` moves with ``sigma * dX``.

    Parameters
    ----------
    X : (P, n, 3) float
        Sphere centres (tank frame) at each pose.
    positions : (P, 3) float
        Sensor centre of each pose.
    K : (P, n, n) float
        The conductance matrices at those poses (:func:`conductance_kernel`).
    signs, offsets, weights, obj_pos, obj_coef, inv_4pi_sigma
        As for :func:`conductance_kernel`.
    dK : (P, 3, n, n) float
        Output.
    """
    n_pose, n, _ = X.shape
    n_img = signs.shape[0]
    n_obj = obj_pos.shape[0]
    dX = np.zeros((3, n, 3))  # d X_p / d theta for theta = x, y, yaw
    dM = np.zeros((3, n, n))
    G = np.zeros((n, 3))
    dG = np.zeros((3, n, 3))
    tmp = np.zeros((n, n))
    for ip in range(n_pose):
        for p in range(n):
            dX[0, p, 0] = 1.0
            dX[1, p, 1] = 1.0
            dX[2, p, 0] = -(X[ip, p, 1] - positions[ip, 1])
            dX[2, p, 1] = X[ip, p, 0] - positions[ip, 0]
        dM[:] = 0.0
        # images: d/dtheta of w / |X_p - (s X_q + o)|
        for p in range(n):
            for q in range(p, n):
                a0 = 0.0
                a1 = 0.0
                a2 = 0.0
                for k in range(n_img):
                    d0 = X[ip, p, 0] - (signs[k, 0] * X[ip, q, 0] + offsets[k, 0])
                    d1 = X[ip, p, 1] - (signs[k, 1] * X[ip, q, 1] + offsets[k, 1])
                    d2 = X[ip, p, 2] - (signs[k, 2] * X[ip, q, 2] + offsets[k, 2])
                    r2 = d0 * d0 + d1 * d1 + d2 * d2
                    w = -weights[k] / (r2 * np.sqrt(r2))
                    a0 += w * d0 * (1.0 - signs[k, 0])
                    a1 += w * d1 * (1.0 - signs[k, 1])
                    a2 += w * (d0 * (dX[2, p, 0] - signs[k, 0] * dX[2, q, 0])
                               + d1 * (dX[2, p, 1] - signs[k, 1] * dX[2, q, 1]))
                dM[0, p, q] = a0
                dM[1, p, q] = a1
                dM[2, p, q] = a2
                dM[0, q, p] = a0
                dM[1, q, p] = a1
                dM[2, q, p] = a2
        # objects: c g_p . g_q, g_p = sum_k -(y - img_k X_p) / |y - img_k X_p|^3 (identity included)
        for o in range(n_obj):
            G[:] = 0.0
            dG[:] = 0.0
            for p in range(n):
                for k in range(-1, n_img):
                    s0 = 1.0 if k < 0 else signs[k, 0]
                    s1 = 1.0 if k < 0 else signs[k, 1]
                    s2 = 1.0 if k < 0 else signs[k, 2]
                    o0 = 0.0 if k < 0 else offsets[k, 0]
                    o1 = 0.0 if k < 0 else offsets[k, 1]
                    o2 = 0.0 if k < 0 else offsets[k, 2]
                    wk = 1.0 if k < 0 else weights[k]
                    e0 = obj_pos[o, 0] - (s0 * X[ip, p, 0] + o0)
                    e1 = obj_pos[o, 1] - (s1 * X[ip, p, 1] + o1)
                    e2 = obj_pos[o, 2] - (s2 * X[ip, p, 2] + o2)
                    r2 = e0 * e0 + e1 * e1 + e2 * e2
                    r = np.sqrt(r2)
                    inv3 = wk / (r2 * r)
                    inv5 = 3.0 * wk / (r2 * r2 * r)
                    G[p, 0] -= e0 * inv3
                    G[p, 1] -= e1 * inv3
                    G[p, 2] -= e2 * inv3
                    for t in range(3):
                        # d g / d theta = (I / r^3 - 3 e e^T / r^5) (s * dX_p/dtheta)
                        v0 = s0 * dX[t, p, 0]
                        v1 = s1 * dX[t, p, 1]
                        v2 = s2 * dX[t, p, 2]
                        ev = e0 * v0 + e1 * v1 + e2 * v2
                        dG[t, p, 0] += v0 * inv3 - e0 * ev * inv5
                        dG[t, p, 1] += v1 * inv3 - e1 * ev * inv5
                        dG[t, p, 2] += v2 * inv3 - e2 * ev * inv5
            for t in range(3):
                for p in range(n):
                    for q in range(n):
                        dM[t, p, q] += obj_coef[o] * (
                            dG[t, p, 0] * G[q, 0] + dG[t, p, 1] * G[q, 1] + dG[t, p, 2] * G[q, 2]
                            + G[p, 0] * dG[t, q, 0] + G[p, 1] * dG[t, q, 1] + G[p, 2] * dG[t, q, 2])
        # dK = -K dM K (dM in ohm)
        for t in range(3):
            for i in range(n):
                for j in range(n):
                    acc = 0.0
                    for l in range(n):
                        acc += dM[t, i, l] * K[ip, l, j]
                    tmp[i, j] = acc * inv_4pi_sigma
            for i in range(n):
                for j in range(n):
                    acc = 0.0
                    for l in range(n):
                        acc += K[ip, i, l] * tmp[l, j]
                    dK[ip, t, i, j] = -acc


@njit(cache=True)
def multipole_image_kernel(c, signs, offsets, weights, out):
    """The images' reflection between points ``c`` (M, 3) up to dipoles, for the sector PSM.

    ``out`` (M, 4, M, 4), filled: for target ``t``, source ``s`` and every
    image ``k`` (``d = c_t - (signs_k * c_s + offsets_k)``, ``r = |d|``, a unit
    current dipole ``b`` at ``s`` imaged as ``signs_k * b``): [potential;
    gradient] at ``t`` per [unit current; unit dipole along x, y, z] at ``s``,
    ``sum w / r``, ``-sum w d / r^3``, ``sum w signs_e d_e / r^3`` and
    ``sum w signs_e (delta_fe / r^3 - 3 d_f d_e / r^5)`` (without the ``1 / (4 pi sigma)``).
    """
    M = c.shape[0]
    K = signs.shape[0]
    for t in range(M):
        for s in range(M):
            acc = np.zeros((4, 4))
            for k in range(K):
                d0 = c[t, 0] - (signs[k, 0] * c[s, 0] + offsets[k, 0])
                d1 = c[t, 1] - (signs[k, 1] * c[s, 1] + offsets[k, 1])
                d2 = c[t, 2] - (signs[k, 2] * c[s, 2] + offsets[k, 2])
                r2 = d0 * d0 + d1 * d1 + d2 * d2
                w1 = weights[k] / np.sqrt(r2)
                w3 = w1 / r2
                w5 = w3 / r2
                d = (d0, d1, d2)
                acc[0, 0] += w1
                for f in range(3):
                    acc[1 + f, 0] -= w3 * d[f]
                    acc[0, 1 + f] += w3 * signs[k, f] * d[f]
                    for e in range(3):
                        h = -3.0 * w5 * d[f] * d[e]
                        if f == e:
                            h += w3
                        acc[1 + f, 1 + e] += h * signs[k, e]
            for a in range(4):
                for b in range(4):
                    out[t, a, s, b] = acc[a, b]
