"""Numerical rank and dominant right singular vectors of a coupling block, by randomised range finding.

The sensor-tank coupling ``A_se`` (sensor rows, tank columns) of a pose sweep
is numerically low rank (a few tens at 1e-6 for angels-4 in the 1 m tank):
the walls see the sensor through a smooth kernel. Its dominant right singular
vectors come from a randomised range finder (Halko, Martinsson & Tropp 2011,
algorithms 4.3/5.1): ``Y = A (A^T A) Omega`` with ``l`` Gaussian columns and one
power step, ``Q = qr(Y)``, the SVD of the small ``Q^T A``. That costs a few
products of ``A`` with ``l`` vectors, against the Gram matrix ``A^T A`` and its
eigendecomposition (cubic in the tank's size) of a direct method. When the
requested tolerance is not reached within the sample (fewer than
``oversampling`` singular values below it), the sample is doubled. The
sample is drawn in single precision (the range it spans is accurate to about
1e-7, far below the usual ``tol``); ``Q^T A`` and its SVD are double.

Example
-------
>>> rng = np.random.default_rng(1)
>>> A = rng.standard_normal((300, 8)) @ rng.standard_normal((8, 200))   # rank 8
>>> Vt, s = right_singular_vectors(A, 1e-10)
>>> Vt.shape, bool(np.allclose(A @ Vt.T @ Vt, A))
((8, 200), True)
"""
from __future__ import annotations

import numpy as np

__all__ = ["right_singular_vectors"]


def right_singular_vectors(A: np.ndarray, tol: float, rank_hint: int = 32, oversampling: int = 16,
                           seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Right singular vectors ``Vt`` (k, N) of ``A`` (M, N) for the singular values above ``tol * s_max``.

    Parameters
    ----------
    A : (M, N) array
    tol : float
        Relative truncation: keep singular values ``s > tol * s[0]``.
    rank_hint : int
        Expected rank (e.g. the previous pose's); the first sample has
        ``rank_hint + oversampling`` columns.
    oversampling : int
        Singular values below the tolerance the sample must contain to be trusted.
    seed : int
        Seed of the Gaussian test matrix (results are reproducible).

    Returns
    -------
    Vt : (k, N) array, orthonormal rows, ``A ~ (A Vt^T) Vt``
    s : (k,) the kept singular values, decreasing
    """
    A = np.asarray(A)
    A32 = A.astype(np.float32)   # the sample only spans the range: single precision halves its cost
    M, N = A.shape
    rng = np.random.default_rng(seed)
    l = min(N, M, max(8, int(rank_hint) + oversampling))
    while True:
        Y = A32 @ rng.standard_normal((N, l)).astype(np.float32)
        Y = A32 @ (A32.T @ Y)                     # one power step: sharper subspace for a slow tail
        Q, _ = np.linalg.qr(Y.astype(float))
        _, s, Vt = np.linalg.svd(Q.T @ A, full_matrices=False)
        k = max(1, int(np.count_nonzero(s > tol * s[0])))
        if l - k >= oversampling or l >= min(N, M):
            return Vt[:k], s[:k]
        l = min(N, M, 2 * l)
