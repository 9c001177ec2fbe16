"""Closed-form conductances that the BEM is verified against.

Example
-------
>>> round(two_sphere_resistance_ohm(0.01, 0.10), 5)  # a = 1 cm, d = 10 cm, sigma = 1 S/m
14.32233
"""
from __future__ import annotations

import numpy as np

__all__ = ["two_sphere_resistance_ohm", "sphere_resistance_to_infinity_ohm", "newman_disc_resistance_ohm"]


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


def newman_disc_resistance_ohm(radius_m: float, sigma_S_per_m: float = 1.0, return_radius_m: float = np.inf) -> float:
    """A disc electrode flush in an insulating plane, against the far field: ``1/(4 sigma a)`` (Newman 1966).

    With a hemispherical return electrode of radius ``b`` centred on the disc,
    the resistance is ``1/(4 sigma a) - 1/(2 pi sigma b)``: the disc's far
    field is the half-space point source's, and its quadrupole term averages
    to zero over the hemisphere, so the error is O((a/b)^4).

    Example
    -------
    >>> round(newman_disc_resistance_ohm(0.01, 1.0), 6)
    25.0
    """
    a, b = float(radius_m), float(return_radius_m)
    if not 0 < a < b:
        raise ValueError(f"disc radius {a} m must be positive and below the return radius {b} m")
    return 1.0 / (4 * sigma_S_per_m * a) - (0.0 if np.isinf(b) else 1.0 / (2 * np.pi * sigma_S_per_m * b))
