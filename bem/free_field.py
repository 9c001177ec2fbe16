"""The isolated sensor's own field in unbounded water, over its meridian half-plane: what a small object sees.

An object at ``p`` changes K, to first order in its size, by the mutual
energy of the unit solutions at ``p`` (a sphere of radius ``b`` and
contrast ``k = sigma_object / sigma``)::

    dK_ij = sigma * sum_l (2 l + 1) gamma_l b^(2 l + 1) <u_i, u_j>_l(p),   gamma_l = l (k - 1) / (l k + l + 1),

where ``<., .>_l`` pairs the degree-``l`` parts of the two potentials about
``p`` over the unit sphere: ``(4 pi / 3) grad u_i . grad u_j`` for the dipole
(l = 1), ``(2 pi / 15) H_i : H_j`` for the quadrupole (l = 2, H the Hessian).
Each term follows from the sphere's reflection of a solid harmonic of degree
``l`` (``-gamma_l (b / r)^(2 l + 1)`` outside it) and Green's second identity
over its surface. Its first term is the familiar ``4 pi sigma chi b^3 grad
u_i . grad u_j`` (chi = 1 for a conductor, -1/2 for an insulator).

Here ``u_i`` is the *isolated* sensor's unit solution (electrode ``i`` at
1 V, the others at 0 V, the whole floating so that no net current leaves:
what K is made of). A sensor of revolution makes it axisymmetric, so it is
tabulated once over its meridian half-plane ``(x, r)`` from the BEM's
representation formula (:func:`meridian_field`), and its gradient and
Hessian at any point of the sensor's frame come from bicubic splines
(:meth:`MeridianField.derivatives`). Beyond the table (``reach_m`` from the
sensor) the field is taken as zero: there an object's change falls off as
the sixth power of the distance.

Example
-------
>>> import numpy as np
>>> from electrosense.meshes import preset
>>> f = meridian_field(preset("angels-2"), edge_length_m=0.01, reach_m=0.1, spacing_m=0.004)
>>> g, H = f.derivatives(np.array([[0.0, 0.05, 0.0]]))
>>> g.shape, H.shape
((1, 2, 3), (1, 2, 3, 3))
>>> bool(np.allclose(g.sum(axis=1), 0, atol=1e-9 * np.abs(g).max()))   # the isolated solutions sum to zero
True
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MeridianField", "meridian_field", "sphere_multipole_factors"]


def sphere_multipole_factors(radius_m: float, contrast_ratio: float) -> tuple[float, float]:
    """``(dipole, quadrupole)``: the factors of ``grad u_i . grad u_j`` and ``H_i : H_j`` in dK_ij / sigma for a
    sphere of ``radius_m`` and conductivity ``contrast_ratio`` times the water's (``inf``: a conductor; module doc).

    >>> sphere_multipole_factors(1.0, np.inf)[0] / (4 * np.pi), sphere_multipole_factors(1.0, 0.0)[0] / (4 * np.pi)
    (1.0, -0.5)
    """
    k = float(contrast_ratio)
    g1 = 1.0 if np.isinf(k) else (k - 1) / (k + 2)
    g2 = 1.0 if np.isinf(k) else 2 * (k - 1) / (2 * k + 3)
    return 4 * np.pi * g1 * radius_m**3, (2 * np.pi / 3) * g2 * radius_m**5


@dataclass
class MeridianField:
    """The isolated unit solutions ``u_i(x, r)`` (n, Nx, Nr) on a grid of the sensor's meridian half-plane."""

    x_m: np.ndarray
    r_m: np.ndarray
    u: np.ndarray
    radius_m: float
    half_length_m: float

    def __post_init__(self):
        from scipy.interpolate import NdBSpline, RectBivariateSpline

        # bicubic interpolating splines of every u_i on the one grid: the same knots, so one tensor-product
        # spline with a coefficient per electrode evaluates them all at once
        splines = [RectBivariateSpline(self.x_m, self.r_m, ui) for ui in self.u]
        tx, tr = splines[0].get_knots()
        coefficients = np.stack([s.get_coeffs().reshape(len(tx) - 4, len(tr) - 4) for s in splines], axis=-1)
        self._spline = NdBSpline((tx, tr), coefficients, 3)

    @property
    def n_electrodes(self) -> int:
        return len(self.u)

    def derivatives(self, points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Gradient (P, n, 3) and Hessian (P, n, 3, 3) of every ``u_i`` at points (P, 3) of the sensor's frame
        (x along its axis); zero beyond the table."""
        q = np.asarray(points_m, float).reshape(-1, 3)
        x = q[:, 0]
        r = np.hypot(q[:, 1], q[:, 2])
        inside = (x >= self.x_m[0]) & (x <= self.x_m[-1]) & (r <= self.r_m[-1])
        P, n = len(q), self.n_electrodes
        grad = np.zeros((P, n, 3))
        hess = np.zeros((P, n, 3, 3))
        if not inside.any():
            return grad, hess
        xi, ri = x[inside], r[inside]
        safe = np.maximum(ri, 1e-9)
        ey, ez = q[inside, 1] / safe, q[inside, 2] / safe
        on_axis = ri < 1e-9
        ey[on_axis], ez[on_axis] = 1.0, 0.0
        xr = np.column_stack([xi, ri])
        fx, fr, fxx, fxr, frr = (self._spline(xr, nu=nu) for nu in ((1, 0), (0, 1), (2, 0), (1, 1), (0, 2)))
        ey, ez, on_axis, safe = ey[:, None], ez[:, None], on_axis[:, None], safe[:, None]   # (p, 1): by electrode
        f_r = np.where(on_axis, frr, fr / safe)   # (1/r) du/dr, its limit on the axis
        grad[inside] = np.stack([fx, fr * ey, fr * ez], axis=-1)
        H = np.zeros((len(xi), n, 3, 3))
        H[..., 0, 0] = fxx
        H[..., 0, 1] = H[..., 1, 0] = fxr * ey
        H[..., 0, 2] = H[..., 2, 0] = fxr * ez
        H[..., 1, 1] = frr * ey**2 + f_r * ez**2
        H[..., 2, 2] = frr * ez**2 + f_r * ey**2
        H[..., 1, 2] = H[..., 2, 1] = (frr - f_r) * ey * ez
        hess[inside] = H
        return grad, hess


def _graded_axis(lo: float, hi: float, fine_lo: float, fine_hi: float, spacing: float, growth: float = 1.15):
    """Points from ``lo`` to ``hi``: uniform at ``spacing`` over [fine_lo, fine_hi], growing geometrically beyond."""
    core = np.linspace(fine_lo, fine_hi, max(2, int(np.ceil((fine_hi - fine_lo) / spacing)) + 1))
    out = [core]
    for end, sign, start in ((hi, 1.0, fine_hi), (lo, -1.0, fine_lo)):
        pts, h, v = [], spacing, start
        while sign * (end - v) > 1e-12:
            h *= growth
            v = v + sign * h
            pts.append(min(v, end) if sign > 0 else max(v, end))
        out.append(np.array(pts))
    return np.unique(np.concatenate(out))


def meridian_field(sensor, edge_length_m: float | None = None, reach_m: float = 0.4,
                   spacing_m: float | None = None, sigma_S_per_m: float = 1.0) -> MeridianField:
    """Tabulate the isolated sensor's unit solutions over its meridian half-plane (module doc).

    The BEM in unbounded water (``edge_length_m``: the sensor mesh's), its representation formula on a grid
    uniform at ``spacing_m`` (default a quarter of the radius) within two radii of the sensor and growing
    beyond, out to ``reach_m`` from it. Grid points inside the body take the value of the nearest point on its
    surface's grid line (the splines stay smooth; only points within a grid step of the surface feel it).
    """
    from electrosense.bem.operators import TriangleSet, layer_matrices
    from electrosense.bem.solve import solve_scene
    from electrosense.meshes.scene import Scene

    R, half = float(sensor.radius_m), 0.5 * float(sensor.length_m)
    h = spacing_m or 0.25 * R
    x = _graded_axis(-half - reach_m, half + reach_m, -half - 2 * R, half + 2 * R, h)
    r = _graded_axis(0.0, R + reach_m, 0.0, 3 * R, h)
    r = r[r >= 0]
    X, Rr = np.meshgrid(x, r, indexing="ij")
    # inside the body: the capsule |x| <= half - R with r <= R, and the two hemispherical ends
    end = np.maximum(np.abs(X) - (half - R), 0.0)
    body = np.hypot(end, Rr) < R
    pts = np.column_stack([X[~body], Rr[~body], np.zeros((~body).sum())])
    sol = solve_scene(Scene(sensor), sigma_S_per_m, edge_length_m=edge_length_m)
    n = sol.n_electrodes
    surfaces = [sol.surface(np.eye(n)[i]) for i in range(n)]
    u_s = np.column_stack([s[0] for s in surfaces])
    q_s = np.column_stack([s[1] for s in surfaces])
    tris = TriangleSet(sol.boundary.triangles_m)
    values = np.empty((len(pts), n))
    for a in range(0, len(pts), 2048):
        S, D = layer_matrices(pts[a:a + 2048], tris)
        values[a:a + 2048] = S @ q_s - D @ u_s
    U = np.zeros((n,) + X.shape)
    U[:, ~body] = values.T
    # fill the body along each grid line of constant x from the first water point above it
    first = np.argmax(~body, axis=1)
    for j in np.flatnonzero(body.any(axis=1)):
        U[:, j, :first[j]] = U[:, j, first[j]][:, None]
    return MeridianField(x, r, U, R, half)
