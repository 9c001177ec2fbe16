"""Symmetric quadrature rules on the reference triangle (barycentric points, weights summing to 1).

Integrals over a flat triangle ``T`` of area ``A``:
``int_T f dS ~= A * sum_k w_k f(l0_k v0 + l1_k v1 + l2_k v2)``.

Example
-------
>>> import numpy as np
>>> from electrosense.bem.quadrature import DUNAVANT_5
>>> bary, w = DUNAVANT_5
>>> float(w.sum()), bary.shape
(1.0, (7, 3))
"""
from __future__ import annotations

import numpy as np

__all__ = ["CENTROID", "DUNAVANT_2", "DUNAVANT_5", "rule_points"]

#: one point, degree 1
CENTROID = (np.array([[1 / 3, 1 / 3, 1 / 3]]), np.array([1.0]))

#: three points, degree 2 (Strang and Fix)
DUNAVANT_2 = (
    np.array([[2 / 3, 1 / 6, 1 / 6], [1 / 6, 2 / 3, 1 / 6], [1 / 6, 1 / 6, 2 / 3]]),
    np.full(3, 1 / 3),
)


def _dunavant_5():
    a1, b1, w1 = 0.059715871789770, 0.470142064105115, 0.132394152788506
    a2, b2, w2 = 0.797426985353087, 0.101286507323456, 0.125939180544827
    bary = np.array(
        [[1 / 3, 1 / 3, 1 / 3], [a1, b1, b1], [b1, a1, b1], [b1, b1, a1], [a2, b2, b2], [b2, a2, b2], [b2, b2, a2]]
    )
    w = np.array([0.225, w1, w1, w1, w2, w2, w2])
    return bary, w / w.sum()


#: seven points, degree 5 (Dunavant 1985)
DUNAVANT_5 = _dunavant_5()


def rule_points(triangles_m: np.ndarray, rule=DUNAVANT_5) -> tuple[np.ndarray, np.ndarray]:
    """Quadrature points (F, K, 3) and weights times area (F, K) for triangles (F, 3, 3)."""
    bary, w = rule
    tri = np.asarray(triangles_m, dtype=float)
    points = np.einsum("kv,fvi->fki", bary, tri)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    return points, area[:, None] * w[None, :]
