"""Potential coefficients of n spheres (the paper's eq. 8) and the isolated conductance matrix.

With the currents ``I`` leaving the spheres and the medium's conductivity
sigma, the sphere potentials are ``V = R I / (4 pi sigma)`` (eq. 7) with::

    R_pq = 1 / a_p          (p == q)
    R_pq = 1 / |c_p - c_q|  (p != q)

An isolated sensor has ``sum(I) = 0`` and a floating far field, so only the
restriction of the potential-coefficient matrix ``M`` (ohm, ``V = M I``) to
zero-sum currents matters. With the paper's ``P`` (n x (n-1): the identity
on the receivers, -1 on the emitter's row) the nodal conductance matrix of
:mod:`electrosense.bem.conductance` is::

    K = P (P^T M P)^-1 P^T,

which is independent of the emitter chosen for ``P``; ``S = K`` without the
emitter's row and column = ``4 pi sigma inv(P^T R P)`` (eq. 14 with the
paper's positive-diagonal sign).

Example
-------
Two spheres far apart: ``K11 = 4 pi sigma / (1/a1 + 1/a2 - 2/L)``.

>>> import numpy as np
>>> R = potential_coefficients(np.array([0.01, 0.02]), np.array([[0.1, 0, 0], [-0.1, 0, 0]]))
>>> K = isolated_conductance(R / (4 * np.pi * 1.0), emitter=2)
>>> bool(np.isclose(K[0, 0], 4 * np.pi / (1 / 0.01 + 1 / 0.02 - 2 / 0.2)))
True
"""
from __future__ import annotations

import numpy as np

__all__ = ["potential_coefficients", "current_projector", "isolated_conductance"]


def potential_coefficients(radii_m: np.ndarray, centres_m: np.ndarray) -> np.ndarray:
    """The paper's R (eq. 8), in 1/m: ``1/a_p`` on the diagonal, ``1/|c_p - c_q|`` off it.

    Parameters
    ----------
    radii_m : (n,) array
    centres_m : (..., n, 3) array
        Sphere centres; leading axes broadcast (one R per pose).
    """
    a = np.asarray(radii_m, dtype=float)
    c = np.asarray(centres_m)
    d = np.linalg.norm(c[..., :, None, :] - c[..., None, :, :], axis=-1)
    n = a.shape[-1]
    eye = np.eye(n, dtype=bool)
    with np.errstate(divide="ignore"):
        R = np.where(eye, 0.0, 1.0 / np.where(eye, 1.0, d))
    return R + np.diag(1.0 / a)


def current_projector(n: int, emitter: int) -> np.ndarray:
    """The paper's P (n x (n-1)): receiver currents -> all currents, with sum zero.

    Columns follow the receivers in electrode order; the emitter's row is -1.
    """
    e = emitter - 1
    if not 0 <= e < n:
        raise ValueError(f"emitter {emitter} is not an electrode number 1..{n}")
    P = np.zeros((n, n - 1))
    receivers = [k for k in range(n) if k != e]
    P[receivers, np.arange(n - 1)] = 1.0
    P[e, :] = -1.0
    return P


def isolated_conductance(M_ohm: np.ndarray, emitter: int) -> np.ndarray:
    """Nodal K (S) of an isolated sensor from its potential coefficients ``V = M I`` (ohm).

    ``K = P (P^T M P)^-1 P^T`` (see the module docstring); M may carry
    leading batch axes.
    """
    M = np.asarray(M_ohm)
    P = current_projector(M.shape[-1], emitter)
    A = np.einsum("ia,...ij,jb->...ab", P, M, P)
    return np.einsum("ia,...ab,jb->...ij", P, np.linalg.inv(A), P)
