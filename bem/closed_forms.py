"""Closed-form conductances that the BEM is verified against.

Example
-------
>>> round(two_sphere_resistance_ohm(0.01, 0.10), 5)  # a = 1 cm, d = 10 cm, sigma = 1 S/m
14.32233
"""
from __future__ import annotations

import numpy as np

__all__ = ["two_sphere_resistance_ohm", "sphere_resistance_to_infinity_ohm"]


def two_sphere_resistance_ohm(radius_m: float, distance_m: float, sigma_S_per_m: float = 1.0, terms: int = 80) -> float:
    """Exact resistance between two equal, isolated spheres (bispherical series, Smythe).

    With ``cosh(beta) = d / (2 a)`` the capacitance coefficients in units of
    4 pi sigma are ``c11 = a sinh(beta) sum 1/sinh((2n-1) beta)`` and
    ``c12 = -a sinh(beta) sum 1/sinh(2n beta)``; the isolated pair's
    resistance is ``p11 + p22 - 2 p12`` with ``p`` the inverse of the
    capacitance matrix.
    """
    a, d = float(radius_m), float(distance_m)
    if not d > 2 * a > 0:
        raise ValueError(f"two spheres of radius {a} m at centre distance {d} m overlap")
    beta = np.arccosh(d / (2 * a))
    n = np.arange(1, terms)
    with np.errstate(over="ignore"):
        c11 = a * np.sinh(beta) * np.sum(1 / np.sinh((2 * n - 1) * beta))
        c12 = -a * np.sinh(beta) * np.sum(1 / np.sinh(2 * n * beta))
    P = np.linalg.inv(4 * np.pi * sigma_S_per_m * np.array([[c11, c12], [c12, c11]]))
    return float(P[0, 0] + P[1, 1] - 2 * P[0, 1])


def sphere_resistance_to_infinity_ohm(radius_m: float, sigma_S_per_m: float = 1.0,
                                      contact_impedance_ohm_m2: float = 0.0) -> float:
    """A sphere electrode against the far field: ``1/(4 pi sigma a) + z_c/(4 pi a^2)``."""
    a = float(radius_m)
    return 1.0 / (4 * np.pi * sigma_S_per_m * a) + contact_impedance_ohm_m2 / (4 * np.pi * a * a)
