"""Measurement protocols from one conductance matrix: four-electrode transfer impedances and drive voltages.

Everything follows from the nodal conductance matrix ``K`` of ALL the
electrodes of a closed tank (:mod:`electrosense.bem.conductance`: ``I_leaving = K V``),
solved once (one factorisation serves every drive pattern):

* a current source drives 1 A from electrode ``a`` into the water and back
  out through electrode ``b``; every other electrode floats (no net
  current). The potentials are ``V = K^+ (e_a - e_b)`` (defined up to a
  constant, which no difference sees);
* the transfer impedance of drive ``(a, b)`` and measurement ``(p, q)`` is
  ``Z = V_p - V_q`` (ohm): the voltage read from ``p`` to ``q`` per ampere;
* the drive pair's own impedance ``V_a - V_b`` carries the contact
  impedances of ``a`` and ``b`` when ``K`` was computed with them;
* on the fish-like bench (fixed voltage) the currents are ``K V`` directly
  (:meth:`electrosense.bem.conductance.ConductanceMatrix.receiver_currents_A`).

Reciprocity: ``Z(a, b; p, q) = Z(p, q; a, b)`` because ``K`` is symmetric.

Example
-------
>>> import numpy as np
>>> g = 1.0  # four electrodes in a row, each joined to the next by 1 S
>>> K = np.array([[g, -g, 0, 0], [-g, 2 * g, -g, 0], [0, -g, 2 * g, -g], [0, 0, -g, g]])
>>> transfer_impedances_ohm(K, [(1, 4)], [(2, 3)]).round(6).tolist()
[[1.0]]
>>> drive_impedances_ohm(K, [(1, 4)]).round(6).tolist()
[3.0]
"""
from __future__ import annotations

import numpy as np

__all__ = ["node_potentials_V", "transfer_impedances_ohm", "drive_impedances_ohm", "adjacent_protocol",
           "involves_drive", "all_pairs", "pattern_voltages_V"]


def _pairs(pairs, n: int, what: str) -> np.ndarray:
    p = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if p.size and (p.min() < 1 or p.max() > n):
        raise ValueError(f"{what}: electrode numbers must lie in 1..{n}, got {sorted(set(p.ravel().tolist()))}")
    if np.any(p[:, 0] == p[:, 1]):
        raise ValueError(f"{what}: a pair joins an electrode to itself: {p[p[:, 0] == p[:, 1]].tolist()}")
    return p


def node_potentials_V(K_S: np.ndarray, drive_pairs) -> np.ndarray:
    """(..., D, n) electrode potentials (mean zero) for 1 A driven through each pair, others floating."""
    K = np.asarray(K_S, dtype=float)
    n = K.shape[-1]
    d = _pairs(drive_pairs, n, "drive pairs")
    I = np.zeros((n, len(d)))
    I[d[:, 0] - 1, np.arange(len(d))] = 1.0
    I[d[:, 1] - 1, np.arange(len(d))] = -1.0
    # K + (1 1^T) s / n is regular (K's null space is the constant), and gives the mean-zero solution
    scale = np.abs(np.trace(K, axis1=-2, axis2=-1))[..., None, None] / n
    V = np.linalg.solve(K + scale * np.ones((n, n)) / n, np.broadcast_to(I, K.shape[:-2] + I.shape))
    return np.swapaxes(V, -1, -2)


def transfer_impedances_ohm(K_S: np.ndarray, drive_pairs, measure_pairs) -> np.ndarray:
    """(..., D, M) four-electrode transfer impedances ``V_p - V_q`` per ampere driven from a to b."""
    n = np.shape(K_S)[-1]
    m = _pairs(measure_pairs, n, "measurement pairs")
    V = node_potentials_V(K_S, drive_pairs)
    return V[..., m[:, 0] - 1] - V[..., m[:, 1] - 1]


def drive_impedances_ohm(K_S: np.ndarray, drive_pairs) -> np.ndarray:
    """(..., D) voltage across each drive pair per ampere (ohm), contact impedances included."""
    n = np.shape(K_S)[-1]
    d = _pairs(drive_pairs, n, "drive pairs")
    V = node_potentials_V(K_S, d)
    idx = np.arange(len(d))
    return V[..., idx, d[:, 0] - 1] - V[..., idx, d[:, 1] - 1]


def adjacent_protocol(ring) -> tuple[np.ndarray, np.ndarray]:
    """Adjacent drive and adjacent measurement on a ring of electrodes (1-based numbers, in ring order).

    Drive k is ``(ring[k], ring[k+1])``, measurement m is ``(ring[m], ring[m+1])``
    (cyclic), as the Goettingen/Sheffield systems do.

    Example
    -------
    >>> d, m = adjacent_protocol([1, 2, 3, 4])
    >>> d.tolist()
    [[1, 2], [2, 3], [3, 4], [4, 1]]
    """
    r = np.asarray(ring, dtype=np.int64).ravel()
    if len(r) < 4 or len(set(r.tolist())) != len(r):
        raise ValueError(f"a ring protocol needs at least 4 distinct electrodes, got {r.tolist()}")
    pairs = np.stack([r, np.roll(r, -1)], axis=1)
    return pairs, pairs.copy()


def involves_drive(drive_pairs, measure_pairs) -> np.ndarray:
    """(D, M) True where a measurement pair shares an electrode with the drive pair."""
    d = np.asarray(drive_pairs).reshape(-1, 2)
    m = np.asarray(measure_pairs).reshape(-1, 2)
    return np.any(d[:, None, :, None] == m[None, :, None, :], axis=(2, 3))


def all_pairs(electrodes) -> np.ndarray:
    """(P, 2) every unordered pair of the given electrodes, each once."""
    e = np.asarray(electrodes, dtype=np.int64).ravel()
    i, j = np.triu_indices(len(e), 1)
    return np.stack([e[i], e[j]], axis=1)


def pattern_voltages_V(K_S: np.ndarray, injection_A, measurement_pattern) -> np.ndarray:
    """(P, M) voltages of current-driven EIT: pattern p injects ``injection_A[:, p]`` (E,) (summing to zero; an
    electrode with no current floats), measurement m reads ``measurement_pattern[:, m] @ V``.

    ``K_S`` (E, E) is the conductance matrix of all the electrodes with their contact impedances (the complete
    electrode model: the 3-D BEM's, or :class:`electrosense.bem.prism_modes.PrismSolution`'s ``K_S``).

    >>> K = np.array([[1.0, -1, 0, 0], [-1, 2, -1, 0], [0, -1, 2, -1], [0, 0, -1, 1]])
    >>> inj = np.array([[1.0], [0.0], [0.0], [-1.0]]); mp = np.array([[1.0, 0], [-1, 1], [0, -1], [0, 0]])
    >>> pattern_voltages_V(K, inj, mp).round(6).tolist()
    [[1.0, 1.0]]
    """
    K = np.asarray(K_S, dtype=float)
    I = np.asarray(injection_A, dtype=float)
    n = K.shape[-1]
    if I.shape[0] != n or np.asarray(measurement_pattern).shape[0] != n:
        raise ValueError(f"{n} electrodes in K, but currents for {I.shape[0]} and a measurement pattern over "
                         f"{np.asarray(measurement_pattern).shape[0]}")
    if np.any(np.abs(I.sum(axis=0)) > 1e-9 * np.abs(I).max(axis=0).clip(1e-300)):
        raise ValueError("a pattern's currents do not sum to zero")
    scale = np.abs(np.trace(K)) / n
    V = np.linalg.solve(K + scale * np.ones((n, n)) / n, I)
    return (np.asarray(measurement_pattern, dtype=float).T @ V).T
