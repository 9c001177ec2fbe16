"""Closed-form integrals of 1/r and of its normal derivative over a flat triangle.

For a point ``x`` and a flat triangle ``T`` with unit normal ``n`` (right-hand
rule on the vertex order):

* :func:`inverse_distance_integral`: ``int_T dS_y / |x - y|`` (Wilton et al.
  1984; Graglia 1993): exact for any ``x``, including ``x`` in ``T``.
* :func:`solid_angle`: ``Omega = int_T n . (y - x) / |y - x|^3 dS_y``, the solid
  angle under which ``T`` is seen from ``x`` (van Oosterom and Strackee 1983),
  positive when ``n`` points away from ``x``. The constant double layer over
  ``T`` is ``-Omega / (4 pi)`` (see :mod:`electrosense.bem.operators`). For ``x`` inside
  ``T`` the formula returns +-2 pi; its principal value is 0 and callers pass
  ``own=True`` for that case.

These are numba kernels on scalars (no allocation) so that the operator
assembly can call them for millions of pairs; the numpy wrappers
:func:`inverse_distance_integrals` and :func:`solid_angles` are for tests
and small jobs.

Example
-------
>>> import numpy as np
>>> from electrosense.bem.triangle_integrals import solid_angles
>>> tri = np.array([[[0, 0, 1], [1, 0, 1], [0, 1, 1]]], float)
>>> bool(solid_angles(np.zeros((1, 3)), tri)[0, 0] > 0)
True
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["inverse_distance_integral", "solid_angle", "inverse_distance_integrals", "solid_angles"]


@njit(cache=True, inline="always")
def solid_angle(x0, x1, x2, a0, a1, a2, b0, b1, b2, c0, c1, c2):
    """Signed solid angle of triangle (a, b, c) seen from x (van Oosterom-Strackee)."""
    r10, r11, r12 = a0 - x0, a1 - x1, a2 - x2
    r20, r21, r22 = b0 - x0, b1 - x1, b2 - x2
    r30, r31, r32 = c0 - x0, c1 - x1, c2 - x2
    l1 = math.sqrt(r10 * r10 + r11 * r11 + r12 * r12)
    l2 = math.sqrt(r20 * r20 + r21 * r21 + r22 * r22)
    l3 = math.sqrt(r30 * r30 + r31 * r31 + r32 * r32)
    num = r10 * (r21 * r32 - r22 * r31) + r11 * (r22 * r30 - r20 * r32) + r12 * (r20 * r31 - r21 * r30)
    den = (
        l1 * l2 * l3
        + (r10 * r20 + r11 * r21 + r12 * r22) * l3
        + (r10 * r30 + r11 * r31 + r12 * r32) * l2
        + (r20 * r30 + r21 * r31 + r22 * r32) * l1
    )
    return 2.0 * math.atan2(num, den)


@njit(cache=True)
def inverse_distance_integral(x0, x1, x2, a0, a1, a2, b0, b1, b2, c0, c1, c2):
    """int_T dS / |x - y| over the flat triangle (a, b, c), exact (Wilton 1984)."""
    e10, e11, e12 = b0 - a0, b1 - a1, b2 - a2
    e20, e21, e22 = c0 - a0, c1 - a1, c2 - a2
    n0 = e11 * e22 - e12 * e21
    n1 = e12 * e20 - e10 * e22
    n2 = e10 * e21 - e11 * e20
    nn = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    n0 /= nn
    n1 /= nn
    n2 /= nn
    d = (x0 - a0) * n0 + (x1 - a1) * n1 + (x2 - a2) * n2
    ad = abs(d)
    p0, p1, p2 = x0 - d * n0, x1 - d * n1, x2 - d * n2  # projection of x on the plane
    total = 0.0
    for k in range(3):
        if k == 0:
            u0, u1, u2, v0, v1, v2 = a0, a1, a2, b0, b1, b2
        elif k == 1:
            u0, u1, u2, v0, v1, v2 = b0, b1, b2, c0, c1, c2
        else:
            u0, u1, u2, v0, v1, v2 = c0, c1, c2, a0, a1, a2
        s0, s1, s2 = v0 - u0, v1 - u1, v2 - u2
        length = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
        s0 /= length
        s1 /= length
        s2 /= length
        m0 = s1 * n2 - s2 * n1  # outward in-plane normal of the edge
        m1 = s2 * n0 - s0 * n2
        m2 = s0 * n1 - s1 * n0
        w0, w1, w2 = u0 - p0, u1 - p1, u2 - p2
        t0 = w0 * m0 + w1 * m1 + w2 * m2
        s_minus = w0 * s0 + w1 * s1 + w2 * s2
        s_plus = s_minus + length
        r0sq = t0 * t0 + d * d
        r_minus = math.sqrt(r0sq + s_minus * s_minus)
        r_plus = math.sqrt(r0sq + s_plus * s_plus)
        if abs(t0) > 1e-14 * length:
            r0 = math.sqrt(r0sq)
            total += t0 * (math.asinh(s_plus / r0) - math.asinh(s_minus / r0))
            if ad > 0.0:
                total -= ad * (
                    math.atan(t0 * s_plus / (r0sq + ad * r_plus)) - math.atan(t0 * s_minus / (r0sq + ad * r_minus))
                )
    return total


def _wrap(kernel, points, triangles):
    points = np.asarray(points, float).reshape(-1, 3)
    tri = np.asarray(triangles, float).reshape(-1, 3, 3)
    out = np.empty((len(points), len(tri)))
    for i, x in enumerate(points):
        for j, t in enumerate(tri):
            out[i, j] = kernel(*x, *t[0], *t[1], *t[2])
    return out


def inverse_distance_integrals(points_m: np.ndarray, triangles_m: np.ndarray) -> np.ndarray:
    """(P, T) array of int_T dS/|x - y| (m) for points (P, 3) and triangles (T, 3, 3)."""
    return _wrap(inverse_distance_integral, points_m, triangles_m)


def solid_angles(points_m: np.ndarray, triangles_m: np.ndarray) -> np.ndarray:
    """(P, T) array of signed solid angles (sr) of triangles (T, 3, 3) seen from points (P, 3)."""
    return _wrap(solid_angle, points_m, triangles_m)
