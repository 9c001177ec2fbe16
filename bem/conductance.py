"""Conductance matrices: the one result type shared by the BEM and the PSM.

Conventions
-----------
``K`` (n x n, siemens) is the nodal conductance matrix::

    K[i, j] = current leaving electrode i into the water (A) when electrode j
              is at 1 V and every other electrode at 0 V, the sensor isolated.

``I_leaving = K @ V`` for any electrode potentials ``V``. K is symmetric,
positive semi-definite, with rows (and columns) summing to zero: adding the
same potential to every electrode changes no current, and the currents of the
isolated sensor sum to zero.

``S`` ((n-1) x (n-1), siemens) is the paper's conductance matrix, K without
the emitter's row and column. With the emitter at potential ``V_e`` and
receiver i at ``V_i``, the voltages ``U_i = V_e - V_i`` give the receiver
currents *into* the receivers (from the water, the bench-log sign)::

    I_into = S @ U.

S has a positive diagonal, as printed in the paper. On the bench all
receivers sit at one potential, ``U_i = U``, so receiver k collects
``I_k = -K[k, e] U`` and its resistance is ``U / I_k``.

Electrodes are numbered 1..n from the head; ``emitter`` is 1-based.
Arrays may carry leading batch axes (one matrix per pose): ``K`` of shape
``(..., n, n)``.

Example
-------
>>> import numpy as np
>>> from electrosense.bem.conductance import ConductanceMatrix
>>> g = 0.05
>>> c = ConductanceMatrix(np.array([[g, -g], [-g, g]]), emitter=2, sigma_S_per_m=1.0)
>>> c.S_S
array([[0.05]])
>>> float(c.resistance_ohm[0])
20.0
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["check_conductivity", "ConductanceMatrix", "K_from_S", "S_from_K", "isolate", "pair_values"]


def check_conductivity(sigma_S_per_m, name: str = "sigma_S_per_m") -> float:
    """The water conductivity as a float, or a ``ValueError`` naming ``name`` if it is not finite and positive.

    >>> check_conductivity(0.0354)
    0.0354
    >>> check_conductivity(-1.0, "--sigma")
    Traceback (most recent call last):
    ...
    ValueError: --sigma must be a positive, finite conductivity (S/m), got -1.0
    """
    try:
        sigma = float(sigma_S_per_m)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a conductivity in S/m, got {sigma_S_per_m!r}") from None
    if not (np.isfinite(sigma) and sigma > 0):
        raise ValueError(f"{name} must be a positive, finite conductivity (S/m), got {sigma_S_per_m}")
    return sigma


def S_from_K(K: np.ndarray, emitter: int) -> np.ndarray:
    """The paper's S: K without the (1-based) emitter's row and column."""
    K = np.asarray(K, dtype=float)
    keep = [k for k in range(K.shape[-1]) if k != emitter - 1]
    return K[..., keep, :][..., :, keep]


def K_from_S(S: np.ndarray, emitter: int) -> np.ndarray:
    """Rebuild the nodal K from the paper's S, using zero row and column sums."""
    S = np.asarray(S, dtype=float)
    m = S.shape[-1]
    n = m + 1
    e = emitter - 1
    if not 0 <= e < n:
        raise ValueError(f"emitter {emitter} is not an electrode number 1..{n}")
    keep = [k for k in range(n) if k != e]
    K = np.zeros(S.shape[:-2] + (n, n))
    K[..., np.ix_(keep, keep)[0], np.ix_(keep, keep)[1]] = S
    col = -S.sum(axis=-1)
    K[..., keep, e] = col
    K[..., e, keep] = col
    K[..., e, e] = S.sum(axis=(-1, -2))
    return K


def pair_values(K: np.ndarray, emitter: int | None) -> np.ndarray:
    """One value per electrode pair (..., n (n - 1) / 2), in ``np.triu_indices(n, 1)`` order, of the symmetric K
    that a numerical ``K`` (..., n, n) stands for: a pair with the emitter from the emitter's column,
    ``K[receiver, emitter]`` (what the bench reads: :meth:`ConductanceMatrix.receiver_currents_A`), every other
    pair the mean of ``K[i, j]`` and ``K[j, i]`` (every pair, with ``emitter`` None).

    A collocation BEM's two estimates of a pair differ by its discretisation error (1e-5 relative for a sensor
    alone, 1e-4 in the middle of a tank, up to 1e-3 with a wall 8 mm from the sensor): a model that keeps one
    number per pair (a tank map, the diagnosis's anchored baseline) and reads receiver currents from the
    emitter's column must keep that column's, or half its receivers carry the other estimate.

    >>> K = np.array([[-2.0, 1.0, 1.0], [1.001, -2.0, 0.999], [1.0, 1.002, -2.0]])
    >>> pair_values(K, emitter=2).tolist()     # pairs (1, 2), (1, 3), (2, 3): column 2, the mean, column 2
    [1.0, 1.0, 1.002]
    >>> pair_values(K, None).tolist()          # the mean of every pair
    [1.0005, 1.0, 1.0005]
    """
    K = np.asarray(K, float)
    n = K.shape[-1]
    i, j = np.triu_indices(n, 1)
    mean = 0.5 * (K[..., i, j] + K[..., j, i])
    if emitter is None:
        return mean
    if not 1 <= int(emitter) <= n:
        raise ValueError(f"emitter {emitter} is not an electrode of a {n}-electrode K")
    e = int(emitter) - 1
    column = np.where(j == e, K[..., i, j], K[..., j, i])   # the receiver's row of the emitter's column
    return np.where((i == e) | (j == e), column, mean)


def isolate(C: np.ndarray) -> np.ndarray:
    """Float the sensor: from the grounded matrix C (currents with the far
    field or ground held at 0 V) to the isolated K, whose currents sum to zero.

    ``K = C - (C 1)(1^T C) / (1^T C 1)``: eliminate the common potential of
    the far field (a Schur complement), as for an electrically isolated sensor
    in unbounded water.
    """
    C = np.asarray(C, dtype=float)
    r = C.sum(axis=-1)
    c = C.sum(axis=-2)
    total = r.sum(axis=-1)
    return C - r[..., :, None] * c[..., None, :] / total[..., None, None]


@dataclass(frozen=True)
class ConductanceMatrix:
    """Nodal conductance matrix K (S) of a sensor, with its emitter and the water's conductivity.

    Parameters
    ----------
    K_S : array (..., n, n)
        Nodal conductance matrix in siemens (see the module docstring).
    emitter : int
        1-based emitter number.
    sigma_S_per_m : float
        Conductivity of the water the matrix was computed for.
    info : dict
        Free-form provenance (model, mesh size, seconds, residues...).
    """

    K_S: np.ndarray
    emitter: int
    sigma_S_per_m: float
    info: dict = field(default_factory=dict, compare=False)

    def __post_init__(self):
        K = np.asarray(self.K_S, dtype=float)
        if K.ndim < 2 or K.shape[-1] != K.shape[-2] or K.shape[-1] < 2:
            raise ValueError(f"K_S must be (..., n, n) with n >= 2, got shape {K.shape}")
        if not 1 <= self.emitter <= K.shape[-1]:
            raise ValueError(f"emitter {self.emitter} is not an electrode number 1..{K.shape[-1]}")
        if not np.all(np.isfinite(K)):
            raise ValueError("K_S contains non-finite entries")
        object.__setattr__(self, "K_S", K)

    # ------------------------------------------------------------------ shapes
    @property
    def n(self) -> int:
        return self.K_S.shape[-1]

    @property
    def receivers(self) -> tuple[int, ...]:
        """1-based receiver numbers in electrode order (the bench log's I<k>_A columns)."""
        return tuple(k for k in range(1, self.n + 1) if k != self.emitter)

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return self.K_S.shape[:-2]

    def __len__(self) -> int:
        return self.batch_shape[0] if self.batch_shape else 1

    def __getitem__(self, index) -> "ConductanceMatrix":
        return ConductanceMatrix(self.K_S[index], self.emitter, self.sigma_S_per_m, self.info)

    # ----------------------------------------------------------------- derived
    @property
    def S_S(self) -> np.ndarray:
        """The paper's S: K without the emitter's row and column (positive diagonal)."""
        return S_from_K(self.K_S, self.emitter)

    def currents_leaving_A(self, V_V: np.ndarray) -> np.ndarray:
        """Currents (A) leaving each electrode into the water for potentials ``V_V`` (..., n)."""
        return np.einsum("...ij,...j->...i", self.K_S, np.asarray(V_V, dtype=float))

    def receiver_currents_A(self, U_V=1.0) -> np.ndarray:
        """Bench currents (..., n-1): into each receiver, emitter at ``U_V`` above the receivers."""
        e = self.emitter - 1
        col = self.K_S[..., :, e]
        rec = [k - 1 for k in self.receivers]
        return -col[..., rec] * np.asarray(U_V, dtype=float)[..., None]

    @property
    def resistance_ohm(self) -> np.ndarray:
        """U/I of each receiver (..., n-1) on the bench (all receivers at one potential)."""
        return 1.0 / self.receiver_currents_A(1.0)

    def scaled_to(self, sigma_S_per_m: float) -> "ConductanceMatrix":
        """The same geometry in water of another conductivity (K is proportional to sigma)."""
        return ConductanceMatrix(self.K_S * (sigma_S_per_m / self.sigma_S_per_m), self.emitter, sigma_S_per_m, self.info)

    @property
    def asymmetry(self) -> float:
        """max |K - K^T| / max |K|: the discrete asymmetry of a numerical K."""
        K = self.K_S
        return float(np.max(np.abs(K - np.swapaxes(K, -1, -2))) / np.max(np.abs(K)))

    @property
    def row_sum_residue(self) -> float:
        """max |sum_j K_ij| / max |K|: how far the currents are from summing to zero."""
        K = self.K_S
        return float(np.max(np.abs(K.sum(axis=-1))) / np.max(np.abs(K)))

    def to_json_dict(self) -> dict:
        """The JSON form written by ``esense conductance`` (and read by ``esense calibrate``)."""
        return {
            "convention": (
                "K_S[i][j]: current (A) leaving electrode i into the water with electrode j at 1 V, "
                "others 0 V, sensor isolated; S_S: K_S without the emitter row/column (current into "
                "receivers per volt of U = V_emitter - V_receiver); electrodes 1-based from the head"
            ),
            "sigma_S_per_m": self.sigma_S_per_m,
            "emitter": self.emitter,
            "receivers": list(self.receivers),
            "K_S": self.K_S.tolist(),
            "S_S": self.S_S.tolist(),
            "asymmetry": self.asymmetry,
            "row_sum_residue": self.row_sum_residue,
        }

    @classmethod
    def from_json_dict(cls, d: dict) -> "ConductanceMatrix":
        try:
            sigma = float(d["sigma_S_per_m"])
            emitter = int(d["emitter"])
        except KeyError as exc:
            raise ValueError(f"conductance JSON lacks the key {exc}") from None
        if "K_S" in d:
            K = np.asarray(d["K_S"], dtype=float)
        elif "S_S" in d:
            K = K_from_S(np.asarray(d["S_S"], dtype=float), emitter)
        else:
            raise ValueError("conductance JSON has neither K_S nor S_S")
        return cls(K, emitter, sigma, {k: v for k, v in d.items() if k not in ("K_S", "S_S")})
