"""Dense collocation matrices of the single- and double-layer operators on flat triangles.

For collocation points ``x_i`` and flat triangles ``T_j`` (constant density,
P0), with the Laplace kernel ``G(x, y) = 1 / (4 pi |x - y|)``:

* ``single_layer[i, j] = int_{T_j} G(x_i, y) dS_y`` (m),
* ``double_layer[i, j] = int_{T_j} dG/dn_y (x_i, y) dS_y = -Omega_ij / (4 pi)``,
  ``n_y`` the triangle's right-hand normal and ``Omega_ij`` the solid angle
  of ``T_j`` seen from ``x_i`` (:func:`electrosense.bem.triangle_integrals.solid_angle`).
  When ``x_i`` is the centroid of its own triangle ``own[i] = j`` the
  principal value is 0.

Integration: the double layer is the exact solid angle (which makes the
rows of ``1/2 I + D`` on a closed surface sum exactly to 0 or 1, the
discrete statement of current conservation), except beyond ``far``
diameters in :func:`mixed_system` where the centroid rule costs a third as
much (pass ``far=np.inf`` for exact row sums); the single layer is exact
(Wilton 1984) for a point within ``near`` triangle diameters of the centroid,
a 7-point degree-5 rule within ``mid`` diameters, the centroid rule beyond.

All kernels are numba-compiled with ``cache=True`` (compiled once per install)
and parallel over the collocation points.

Example
-------
>>> import numpy as np, trimesh
>>> from electrosense.bem.operators import double_layer
>>> s = trimesh.creation.icosphere(2)
>>> tri = s.vertices[s.faces]
>>> D = double_layer(tri.mean(axis=1), tri, own=np.arange(len(tri)))
>>> bool(np.allclose(D.sum(axis=1), -0.5))   # outward normals, point on the surface
True
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from electrosense.bem.quadrature import DUNAVANT_5, rule_points
from electrosense.bem.triangle_integrals import inverse_distance_integral, solid_angle

__all__ = ["single_layer", "double_layer", "layer_matrices", "mixed_system", "mixed_system_reduced", "mixed_entries",
           "TriangleSet", "NEAR", "MID", "FAR"]

#: distance (in triangle diameters) below which the single layer is integrated exactly
NEAR = 2.0
#: distance (in triangle diameters) below which the 7-point rule is used
MID = 5.0

#: distance (in triangle diameters) beyond which the double layer uses the centroid rule in
#: :func:`mixed_system` (``np.inf``: always the exact solid angle)
FAR = 8.0

FOUR_PI = 4.0 * math.pi


class TriangleSet:
    """Triangles (T, 3, 3) with what the kernels need precomputed (centroids, areas, diameters, rule points)."""

    def __init__(self, triangles_m: np.ndarray):
        tri = np.ascontiguousarray(triangles_m, dtype=float).reshape(-1, 3, 3)
        self.triangles = tri
        self.centroids = tri.mean(axis=1)
        self.areas = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        self.diameters = np.linalg.norm(tri[:, [1, 2, 0]] - tri, axis=2).max(axis=1)
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        self.normals = cross / np.maximum(np.linalg.norm(cross, axis=1, keepdims=True), 1e-300)
        points, weights = rule_points(tri, DUNAVANT_5)
        self.rule_points = np.ascontiguousarray(points)
        self.rule_weights = np.ascontiguousarray(weights)

    def __len__(self) -> int:
        return len(self.triangles)


@njit(cache=True, inline="always")
def _pair(x0, x1, x2, j, is_own, tri, cen, area, diam, nrm, qp, qw, near2, mid2, far2):
    """(single layer, double layer) of triangle j at x."""
    t = tri[j]
    d0, d1, d2 = x0 - cen[j, 0], x1 - cen[j, 1], x2 - cen[j, 2]
    r2 = d0 * d0 + d1 * d1 + d2 * d2
    h2 = diam[j] * diam[j]
    if is_own:
        dl = 0.0
    elif r2 > far2 * h2:
        dl = area[j] * (nrm[j, 0] * d0 + nrm[j, 1] * d1 + nrm[j, 2] * d2) / (FOUR_PI * r2 * math.sqrt(r2))
    else:
        dl = -solid_angle(x0, x1, x2, t[0, 0], t[0, 1], t[0, 2], t[1, 0], t[1, 1], t[1, 2],
                          t[2, 0], t[2, 1], t[2, 2]) / FOUR_PI
    if r2 < near2 * h2:
        sl = inverse_distance_integral(x0, x1, x2, t[0, 0], t[0, 1], t[0, 2], t[1, 0], t[1, 1], t[1, 2],
                                       t[2, 0], t[2, 1], t[2, 2]) / FOUR_PI
    elif r2 < mid2 * h2:
        sl = 0.0
        for k in range(qp.shape[1]):
            e0, e1, e2 = x0 - qp[j, k, 0], x1 - qp[j, k, 1], x2 - qp[j, k, 2]
            sl += qw[j, k] / math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        sl /= FOUR_PI
    else:
        sl = area[j] / (FOUR_PI * math.sqrt(r2))
    return sl, dl


@njit(parallel=True, cache=True)
def _layers_kernel(points, own, tri, cen, area, diam, nrm, qp, qw, near2, mid2, far2, S, D):
    n, m = points.shape[0], tri.shape[0]
    for i in prange(n):
        x0, x1, x2 = points[i, 0], points[i, 1], points[i, 2]
        for j in range(m):
            sl, dl = _pair(x0, x1, x2, j, own[i] == j, tri, cen, area, diam, nrm, qp, qw, near2, mid2, far2)
            S[i, j] = sl
            D[i, j] = dl


@njit(parallel=True, cache=True)
def _mixed_kernel(points, own, tri, cen, area, diam, nrm, qp, qw, near2, mid2, far2, c_single, c_double,
                          group, column_class, A, B):
    n, m = points.shape[0], tri.shape[0]
    for i in prange(n):
        x0, x1, x2 = points[i, 0], points[i, 1], points[i, 2]
        for j in range(m):
            is_own = own[i] == j
            sl, dl = _pair(x0, x1, x2, j, is_own, tri, cen, area, diam, nrm, qp, qw, near2, mid2, far2)
            h = dl + 0.5 if is_own else dl
            A[i, column_class[j]] += c_single[j] * sl + c_double[j] * h
            g = group[j]
            if g >= 0:
                B[i, g] += h


def _prepare(points, triangles, own):
    tris = triangles if isinstance(triangles, TriangleSet) else TriangleSet(triangles)
    pts = np.ascontiguousarray(points, dtype=float).reshape(-1, 3)
    own = np.full(len(pts), -1, np.int64) if own is None else np.ascontiguousarray(own, dtype=np.int64)
    if own.shape != (len(pts),):
        raise ValueError(f"own must have one entry per point ({len(pts)}), got shape {own.shape}")
    return pts, tris, own


def layer_matrices(points_m, triangles, own=None, near=NEAR, mid=MID, far=np.inf) -> tuple[np.ndarray, np.ndarray]:
    """Single- and double-layer matrices (P, T) at points (P, 3) for triangles (T, 3, 3) or a TriangleSet.

    ``own[i]`` is the triangle whose centroid point ``i`` is (-1: none).
    """
    pts, t, own = _prepare(points_m, triangles, own)
    S = np.empty((len(pts), len(t)))
    D = np.empty((len(pts), len(t)))
    _layers_kernel(pts, own, t.triangles, t.centroids, t.areas, t.diameters, t.normals, t.rule_points,
                   t.rule_weights, near * near, mid * mid, far * far, S, D)
    return S, D


def single_layer(points_m, triangles, own=None) -> np.ndarray:
    """Collocation matrix of the single layer ``int G dS`` (m), see the module docstring."""
    return layer_matrices(points_m, triangles, own)[0]


def double_layer(points_m, triangles, own=None) -> np.ndarray:
    """Collocation matrix of the double layer ``int dG/dn_y dS = -Omega/(4 pi)``, principal value on ``own``."""
    return layer_matrices(points_m, triangles, own)[1]


def mixed_system(points_m, triangles, own, c_single, c_double, group, n_groups, out=None, near=NEAR, mid=MID,
                 far=FAR):
    """Fused assembly of a mixed boundary-value system without storing S and D.

    Returns ``A`` (P, T) with ``A[i, j] = c_single[j] S[i, j] + c_double[j] H[i, j]``,
    ``H = 1/2 I_own + D``, and ``B`` (P, n_groups) with
    ``B[i, g] = sum over j in group g of H[i, j]`` (``group[j] = -1``: none).
    ``out`` may pass a preallocated (P, T) array for ``A``.
    """
    pts, t, own = _prepare(points_m, triangles, own)
    if out is None:
        A = np.zeros((len(pts), len(t)))
    else:
        A = out
        A.fill(0.0)
    B = np.zeros((len(pts), max(int(n_groups), 1)))
    every_column = np.arange(len(t), dtype=np.int64)  # the full system: one class per triangle
    _mixed_kernel(pts, own, t.triangles, t.centroids, t.areas, t.diameters, t.normals, t.rule_points,
                  t.rule_weights, near * near, mid * mid, far * far, np.ascontiguousarray(c_single, dtype=float),
                  np.ascontiguousarray(c_double, dtype=float), np.ascontiguousarray(group, dtype=np.int64),
                  every_column, A, B)
    return A, B[:, : int(n_groups)]


def mixed_system_reduced(points_m, triangles, own, c_single, c_double, group, n_groups, column_class, n_classes,
                         near=NEAR, mid=MID, far=FAR):
    """:func:`mixed_system` with the columns summed by class: ``A[i, c] = sum over j in class c``.

    For unknowns that are constant over each class of triangles (a reduced
    basis), without ever storing the full matrix.
    """
    pts, t, own = _prepare(points_m, triangles, own)
    A = np.zeros((len(pts), int(n_classes)))
    B = np.zeros((len(pts), max(int(n_groups), 1)))
    _mixed_kernel(pts, own, t.triangles, t.centroids, t.areas, t.diameters, t.normals, t.rule_points,
                  t.rule_weights, near * near, mid * mid, far * far, np.ascontiguousarray(c_single, dtype=float),
                  np.ascontiguousarray(c_double, dtype=float), np.ascontiguousarray(group, dtype=np.int64),
                  np.ascontiguousarray(column_class, dtype=np.int64), A, B)
    return A, B[:, : int(n_groups)]


@njit(cache=True)
def _entries_kernel(points, rows, cols, tri, cen, area, diam, nrm, qp, qw, near2, mid2, far2, c_single, c_double,
                    out):
    # serial: a row or a column is short, and numba's threads started for each one between BLAS calls (whose
    # threads spin meanwhile) made the cross approximation 5-15x slower (measured)
    n_cols = cols.shape[0]
    for ab in range(rows.shape[0] * n_cols):
        a, b = ab // n_cols, ab % n_cols
        i, j = rows[a], cols[b]
        sl, dl = _pair(points[i, 0], points[i, 1], points[i, 2], j, False, tri, cen, area, diam, nrm, qp, qw,
                       near2, mid2, far2)
        out[a, b] += c_single[j] * sl + c_double[j] * dl


def mixed_entries(points_m, triangles, rows, cols, c_single, c_double, out=None, near=NEAR, mid=MID, far=FAR):
    """The entries ``(rows, cols)`` of :func:`mixed_system`'s ``A`` for points off the triangles (no point is a
    triangle's own centroid: an image, a point of another surface), ``c_single S + c_double D`` with the
    coefficients of each column, added to ``out`` (len(rows), len(cols)) where given: a row or a column of a
    block, without the block (:mod:`electrosense.bem.cross_approximation`).

    >>> import trimesh
    >>> s = trimesh.creation.icosphere(1)
    >>> t = TriangleSet(s.vertices[s.faces])
    >>> x = t.centroids + [3.0, 0.0, 0.0]
    >>> ones, zeros = np.ones(len(t)), np.zeros(len(t))
    >>> A, _ = mixed_system(x, t, None, ones, zeros, np.full(len(t), -1), 0)
    >>> rows, cols = np.array([4, 1]), np.array([0, 7, 2])
    >>> bool(np.allclose(mixed_entries(x, t, rows, cols, ones, zeros), A[np.ix_(rows, cols)]))
    True
    """
    t = triangles if isinstance(triangles, TriangleSet) else TriangleSet(triangles)
    pts = np.ascontiguousarray(points_m, dtype=float).reshape(-1, 3)
    rows = np.ascontiguousarray(np.atleast_1d(rows), dtype=np.int64)
    cols = np.ascontiguousarray(np.atleast_1d(cols), dtype=np.int64)
    if out is None:
        out = np.zeros((len(rows), len(cols)))
    _entries_kernel(pts, rows, cols, t.triangles, t.centroids, t.areas, t.diameters, t.normals, t.rule_points,
                    t.rule_weights, near * near, mid * mid, far * far, np.ascontiguousarray(c_single, dtype=float),
                    np.ascontiguousarray(c_double, dtype=float), out)
    return out
