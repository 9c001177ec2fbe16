"""A low-rank block from a few of its rows and columns: adaptive cross approximation with partial pivoting.

A block whose kernel is smooth, such as the sensor's own image in a wall
(:meth:`electrosense.bem.PoseSweep._sensor_block_at`: every image point is
at least twice the gap from the sensor), is numerically of low rank: 36 to
56 at 1e-6 of its largest singular value for a random 4-electrode sensor of
8 242 triangles 5-12 mm from a wall. Assembling it whole costs ``m n``
kernel evaluations (and its SVD more); the cross approximation (Bebendorf
2000, *Numer. Math.* 86, 565; Bebendorf & Rjasanow 2003, *Computing* 70, 1)
builds ``M ~ U V`` from ``k`` rows and ``k`` columns, ``k (m + n)``
evaluations: each step takes the residual's row ``i``, its largest entry's
column ``j``, the residual's column ``j``, and the next row where that column
is largest. It stops when a step's rank-one term is below ``tol`` of the
approximation's Frobenius norm on two steps running, and then checks
``checks`` random rows it has not used: their residual, scaled to the whole
block, must be below ``tol`` too, else the worst of them is the next pivot
row (partial pivoting alone can miss a part of the block that its pivots
never visit). A block that does not converge by ``max_rank`` returns None:
the caller assembles it.

:func:`recompressed` turns ``U V`` into orthonormal factors truncated at a
relative singular value, as :func:`electrosense.bem.low_rank.right_singular_vectors`
does for an assembled block.

Example
-------
>>> import numpy as np
>>> x, y = np.linspace(0.0, 1.0, 400), np.linspace(3.0, 4.0, 300)
>>> M = 1.0 / np.abs(x[:, None] - y[None, :])                # a smooth kernel between separated sets
>>> U, V = cross_approximation(lambda i: M[i], lambda j: M[:, j], M.shape, 1e-10)
>>> U.shape[1] < 20, bool(np.abs(U @ V - M).max() < 1e-9 * np.abs(M).max())
(True, True)
"""
from __future__ import annotations

import numpy as np

__all__ = ["cross_approximation", "recompressed"]


def cross_approximation(row, column, shape: tuple[int, int], tol: float, max_rank: int | None = None,
                        first_row: int = 0, checks: int = 8, seed: int = 0):
    """``(U, V)`` with ``M ~ U @ V`` to ``tol`` of ``|M|_F`` from rows and columns of ``M`` (m, n), or None.

    Parameters
    ----------
    row, column : callable
        ``row(i)`` the block's row ``i`` (n,), ``column(j)`` its column ``j`` (m,).
    shape : (m, n)
    tol : float
        Relative accuracy in the Frobenius norm.
    max_rank : int, optional
        The most terms (default ``min(m, n) // 4``): a block that needs more is not worth approximating.
    first_row : int
        The first pivot row (a row the block is largest on converges fastest).
    checks : int
        Random rows that check the approximation once the steps have converged.
    seed : int
        Seed of the check rows (results are reproducible).

    Returns
    -------
    (U (m, k), V (k, n)), or None where ``max_rank`` terms did not reach ``tol``.
    """
    m, n = shape
    max_rank = min(m, n) // 4 if max_rank is None else min(int(max_rank), m, n)
    rng = np.random.default_rng(seed)
    U, V = np.zeros((m, max_rank)), np.zeros((max_rank, n))
    used_rows = np.zeros(m, bool)
    norm2, k, converged_steps, i = 0.0, 0, 0, int(first_row)
    while k < max_rank:
        used_rows[i] = True
        r = row(i) - U[i, :k] @ V[:k]
        j = int(np.argmax(np.abs(r)))
        if r[j] == 0.0:                         # this row is already exact: any other row
            free = np.flatnonzero(~used_rows)
            if len(free) == 0:
                break
            i = int(rng.choice(free))
            continue
        v = r / r[j]
        u = column(j) - U[:, :k] @ V[:k, j]
        norm2 += 2.0 * float((U[:, :k].T @ u) @ (V[:k] @ v)) + float(u @ u) * float(v @ v)
        U[:, k], V[k] = u, v
        k += 1
        converged_steps = converged_steps + 1 if np.sqrt((u @ u) * (v @ v)) <= tol * np.sqrt(norm2) else 0
        if converged_steps >= 2:
            free = np.flatnonzero(~used_rows)
            test = rng.choice(free, size=min(checks, len(free)), replace=False)
            residual = np.array([row(t) for t in test]) - U[test, :k] @ V[:k]
            per_row = np.sum(residual**2, axis=1)
            if len(test) == 0 or np.sqrt(per_row.sum() * m / len(test)) <= tol * np.sqrt(norm2):
                return U[:, :k], V[:k]
            i, converged_steps = int(test[np.argmax(per_row)]), 0
            continue
        score = np.abs(u)
        score[used_rows] = -1.0
        i = int(np.argmax(score))
    return None


def recompressed(U: np.ndarray, V: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(P, Qt, s)`` with ``U @ V ~ P @ Qt``, ``Qt`` (r, n) orthonormal rows, ``P = (U @ V) @ Qt.T`` and ``s``
    the singular values kept (those above ``tol * s[0]``).

    >>> rng = np.random.default_rng(0)
    >>> U, V = rng.standard_normal((50, 6)), rng.standard_normal((6, 40))
    >>> P, Qt, s = recompressed(np.hstack([U, U]), np.vstack([V, V]), 1e-12)    # rank 6 written as 12
    >>> len(s), bool(np.allclose(P @ Qt, 2 * U @ V)), bool(np.allclose(Qt @ Qt.T, np.eye(6)))
    (6, True, True)
    """
    Qu, Ru = np.linalg.qr(U)
    Qv, Rv = np.linalg.qr(V.T)
    W, s, Zt = np.linalg.svd(Ru @ Rv.T)
    r = max(1, int(np.count_nonzero(s > tol * s[0])))
    return Qu @ (W[:, :r] * s[:r]), (Qv @ Zt[:r].T).T, s[:r]
