"""Collocation matrices of the 2-D single and double layers of ``Delta u - k^2 u = 0`` on straight segments.

Green's function ``G_k(r) = K0(k r) / (2 pi)`` (``k > 0``) and ``G_0(r) = -ln(r) / (2 pi)``
(Laplace). For collocation points ``x_i`` and segments ``j`` (constant density, P0):

* ``S[i, j] = int_j G_k(|x_i - y|) ds_y``;
* ``D[i, j] = int_j dG_k/dn_y (x_i, y) ds_y``, ``n_y`` the segment's right-hand
  normal; 0 on the point's own segment (principal value).

The logarithm and the Laplace double layer are integrated in closed form for
every pair; what ``K0`` adds to them (smooth) by composite Gauss-Legendre
panels no longer than ``1 / (2 k)``, so that the kernel's decay over ``1 / k``
is resolved at any mode; pairs farther apart than ``cutoff / k`` are 0
(``K0(40) ~ 2e-18``).

Example
-------
A closed polygon's double layer sums to -1/2 at its own vertices' midpoints
(Laplace), and the single layer of a long segment tends to ``1 / (2 k)`` at
its middle as ``k`` grows:

>>> t = np.linspace(0, 2 * np.pi, 41)[:-1]
>>> p = np.stack([np.cos(t), np.sin(t)], 1)
>>> a, b = p, np.roll(p, -1, 0)
>>> S, D = layer_matrices_2d(0.5 * (a + b), a, b, 0.0, own=np.arange(40))
>>> bool(np.allclose(D.sum(1), -0.5))
True
>>> S, D = layer_matrices_2d(np.array([[0.5, 0.0]]), np.array([[0.0, 0.0]]), np.array([[1.0, 0.0]]), 200.0, own=[0])
>>> round(float(S[0, 0] * 2 * 200.0), 4)
1.0
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

__all__ = ["layer_matrices_2d", "log_integral", "PairGeometry", "NEAR_2D", "CUTOFF_2D"]

#: pairs closer than NEAR_2D segment lengths get the logarithm's closed form
NEAR_2D = 3.0
#: beyond ``CUTOFF_2D / k`` the modified Helmholtz kernels are taken as 0
CUTOFF_2D = 40.0

_GL_X, _GL_W = np.polynomial.legendre.leggauss(4)
_GL_X2, _GL_W2 = np.polynomial.legendre.leggauss(2)


def log_integral(t0, d, L):
    """``int_0^L ln sqrt((t - t0)^2 + d^2) dt`` (arrays broadcast).

    >>> round(float(log_integral(0.5, 0.0, 1.0)), 6)          # int_{-1/2}^{1/2} ln|t| dt = ln(1/2) - 1
    -1.693147
    """
    t0, d, L = np.broadcast_arrays(np.asarray(t0, float), np.asarray(d, float), np.asarray(L, float))

    def F(u):
        r2 = u * u + d * d
        with np.errstate(divide="ignore", invalid="ignore"):
            lg = np.where(r2 > 0, 0.5 * u * np.log(np.where(r2 > 0, r2, 1.0)), 0.0)
            at = np.where(d != 0, d * np.arctan(u / np.where(d != 0, d, 1.0)), 0.0)
        return lg - u + at

    return F(L - t0) - F(-t0)


def _geometry(points, a, b):
    x = np.asarray(points, float)[:, None, :]
    a = np.asarray(a, float)[None]
    b = np.asarray(b, float)[None]
    L = np.linalg.norm(b - a, axis=2)
    tau = (b - a) / L[..., None]
    nu = np.stack([tau[..., 1], -tau[..., 0]], axis=-1)
    t0 = np.sum((x - a) * tau, axis=2)
    d = np.sum((x - a) * nu, axis=2)
    # distance to the segment: along-line excess beyond the ends, and the normal offset
    excess = np.where(t0 < 0, -t0, np.where(t0 > L, t0 - L, 0.0))
    rmin = np.hypot(excess, d)
    return t0, d, np.broadcast_to(L, t0.shape), rmin


@njit(cache=True, inline="always")
def _bessel_k0_k1(x):
    """K0(x) and x K1(x) for x > 0 (Abramowitz and Stegun 9.8.5-9.8.8, relative error below 2.2e-7)."""
    if x <= 2.0:
        t = 0.25 * x * x
        u = (x / 3.75) ** 2
        i0 = 1.0 + u * (3.5156229 + u * (3.0899424 + u * (1.2067492 + u * (0.2659732 + u * (0.0360768
                                                                                             + u * 0.0045813)))))
        i1x = 0.5 + u * (0.87890594 + u * (0.51498869 + u * (0.15084934 + u * (0.02658733 + u * (0.00301532
                                                                                                 + u * 0.00032411)))))
        lg = math.log(0.5 * x)
        k0 = -lg * i0 + (-0.57721566 + t * (0.42278420 + t * (0.23069756 + t * (0.03488590 + t * (0.00262698
                                                                                                  + t * (0.00010750 + t * 0.0000074))))))
        xk1 = x * x * lg * i1x + 1.0 + t * (0.15443144 + t * (-0.67278579 + t * (-0.18156897 + t * (
            -0.01919402 + t * (-0.00110404 + t * -0.00004686)))))
        return k0, xk1
    y = 2.0 / x
    e = math.exp(-x) / math.sqrt(x)
    k0 = e * (1.25331414 + y * (-0.07832358 + y * (0.02189568 + y * (-0.01062446 + y * (0.00587872
                                                                                     + y * (-0.00251540 + y * 0.00053208))))))
    k1 = e * (1.25331414 + y * (0.23498619 + y * (-0.03655620 + y * (0.01504268 + y * (-0.00780353
                                                                                    + y * (0.00325614 + y * -0.00068245))))))
    return k0, x * k1


@njit(parallel=True, cache=True)
def _helmholtz_kernel(t0, d, L, rmin, lap_s, lap_d, k, near_factor, cutoff, gx, gw, gx2, gw2, S, D):
    P, Sn = t0.shape
    inv2pi = 1.0 / (2.0 * math.pi)
    for i in prange(P):
        for j in range(Sn):
            if k * rmin[i, j] >= cutoff:
                continue
            Lj = L[i, j]
            near = rmin[i, j] < near_factor * Lj
            m = max(1, int(math.ceil(2.0 * k * Lj)))
            if m > 128:
                m = 128
            # far pairs: two Gauss points per panel (error ~ (L / r)^4)
            xs, ws = (gx, gw) if near or rmin[i, j] < 2.0 * near_factor * Lj else (gx2, gw2)
            s_acc = 0.0
            d_acc = 0.0
            dd = d[i, j]
            for p in range(m):
                for q in range(xs.shape[0]):
                    tq = (p + 0.5 * (xs[q] + 1.0)) * Lj / m
                    u = tq - t0[i, j]
                    r = math.sqrt(u * u + dd * dd)
                    k0, xk1 = _bessel_k0_k1(k * r)
                    w = ws[q] * 0.5 * Lj / m
                    if near:
                        s_acc += w * (k0 + math.log(r))
                        d_acc += w * dd / (r * r) * (xk1 - 1.0)
                    else:
                        s_acc += w * k0
                        d_acc += w * dd / (r * r) * xk1
            if near:
                S[i, j] = (s_acc - lap_s[i, j]) * inv2pi
                D[i, j] = d_acc * inv2pi + lap_d[i, j]
            else:
                S[i, j] = s_acc * inv2pi
                D[i, j] = d_acc * inv2pi


class PairGeometry:
    """What the layers of every mode share for points and segments: each pair's along-line position ``t0``, normal
    offset ``d``, segment length, distance, and the Laplace parts in closed form (the logarithm's integral on
    near pairs, the double layer's angle)."""

    def __init__(self, points, a, b, own=None):
        t0, d, L, rmin = _geometry(points, a, b)
        P, Sn = t0.shape
        own = np.full(P, -1) if own is None else np.asarray(own)
        is_own = np.zeros((P, Sn), bool)
        hit = own >= 0
        is_own[np.flatnonzero(hit), own[hit]] = True
        d = np.where(is_own, 0.0, d)
        with np.errstate(divide="ignore", invalid="ignore"):
            dsafe = np.where(np.abs(d) > 1e-14 * L, d, 0.0)
            one = np.where(dsafe != 0, dsafe, 1.0)
            lap_d = np.where(dsafe != 0, np.arctan((L - t0) / one) - np.arctan(-t0 / one), 0.0) / (2 * np.pi)
        lap_d[is_own] = 0.0
        self.t0, self.d, self.L, self.rmin, self.is_own, self.lap_d = t0, d, np.ascontiguousarray(L), rmin, is_own, lap_d
        near = rmin < NEAR_2D * L
        self.lap_s = np.zeros((P, Sn))
        self.lap_s[near] = log_integral(t0[near], d[near], L[near])
        self._laplace_s = None

    def laplace_single(self) -> np.ndarray:
        if self._laplace_s is None:
            self._laplace_s = -log_integral(self.t0, self.d, self.L) / (2 * np.pi)
        return self._laplace_s


def layer_matrices_2d(points, a, b, k: float, own=None, geometry: PairGeometry | None = None):
    """``S`` and ``D`` (P, S) of the modified Helmholtz equation of wavenumber ``k`` (1/m; 0: Laplace).

    ``points`` (P, 2), segments ``a`` -> ``b`` (S, 2); ``own[i]`` the segment whose
    midpoint point i is (-1: none). ``geometry``: the pairs' :class:`PairGeometry`, reused across modes.
    """
    g = PairGeometry(points, a, b, own) if geometry is None else geometry
    if k == 0:
        return g.laplace_single(), g.lap_d
    S = np.zeros(g.t0.shape)
    D = np.zeros(g.t0.shape)
    _helmholtz_kernel(g.t0, g.d, g.L, g.rmin, g.lap_s, g.lap_d, float(k), NEAR_2D, CUTOFF_2D, _GL_X, _GL_W,
                      _GL_X2, _GL_W2, S, D)
    D[g.is_own] = 0.0
    return S, D
