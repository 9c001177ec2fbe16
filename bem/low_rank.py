"""Numerical rank and dominant right singular vectors of a coupling block, by blocked randomised range finding.

The sensor-tank coupling ``A_se`` (sensor rows, tank columns) of a pose sweep
is numerically low rank (a few tens at 1e-6 for angels-4 in the 1 m tank, 100
to 350 for a 5-electrode sensor whose tips come near the walls, about 600 with
a tip 5 mm from a wall on a 4 400-triangle tank mesh): the walls see
the sensor through a smooth kernel. Its dominant right singular vectors come
from a randomised range finder (Halko, Martinsson & Tropp 2011, algorithms
4.3/5.1) grown block by block until the rank is revealed (the blocked scheme
of Martinsson & Voronin 2016, *SIAM J. Sci. Comput.* 38(5), S485): each block
of ``block`` Gaussian columns gives ``Y = A (A^T A) Omega`` (one power step:
a sharper subspace for a slow tail), orthogonalised against the basis so far
(twice: block Gram-Schmidt), so that the basis ``Q`` and ``B = Q^T A`` grow by
a block's rows each time and nothing is computed twice. The basis stops
growing when ``oversampling`` of the sample's singular values (those of ``B``,
from its small Gram matrix ``B B^T``, grown by a block each time; from ``B``'s
SVD for a tolerance below :data:`GRAM_RESOLUTION`) are below the tolerance,
and the Gram matrix's eigenvectors give the result (``B``'s own SVD below that
resolution): the sample costs about the rank, not a
worst-case guess (a pose 1.5-2x faster than with a first sample of 1.5x the
first pose's rank, for a random 5-electrode sensor in a 0.67 x 0.44 m box
whose ranks vary from 100 to 340 over the tank; K within 8e-7). A test on the
newest block's singular values alone stops far too late on such a tail: the
single-precision power step leaves the residual's directions in rounding noise.
The sample is drawn in single precision; the basis and ``B`` are double. The
power step in single precision squares what it resolves: the kept span
leaves 1-3e-5 of ``s_max`` of ``A`` out at ``tol = 1e-6`` (a 5-electrode
sensor 5 mm from a wall, ranks 171 and 591), where the span of the exact SVD
leaves 1e-6, and yet the sweep's K is within 1e-6 of that with the exact SVD
(the coupling's small directions barely reach the electrodes). The result
depends on ``A`` and the seed only.

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

__all__ = ["right_singular_vectors", "GRAM_RESOLUTION"]

#: the smallest relative singular value the Gram matrix ``B B^T`` resolves in double precision (its eigenvalues
#: carry an absolute error of about 1e-14 of the largest): below it, the stopping test takes the SVD of ``B``
GRAM_RESOLUTION = 1e-6


def right_singular_vectors(A: np.ndarray, tol: float, block: int = 64, oversampling: int = 48,
                           seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Right singular vectors ``Vt`` (k, N) of ``A`` (M, N) for the singular values above ``tol * s_max``.

    Parameters
    ----------
    A : (M, N) array
    tol : float
        Relative truncation: keep singular values ``s > tol * s[0]``.
    block : int
        Gaussian columns added to the sample at each step.
    oversampling : int
        Singular values below the tolerance the sample must contain to be trusted.
    seed : int
        Seed of the Gaussian test matrices (results are reproducible).

    Returns
    -------
    Vt : (k, N) array, orthonormal rows, ``A ~ (A Vt^T) Vt``
    s : (k,) the kept singular values, decreasing
    """
    A = np.asarray(A, float)
    A32 = A.astype(np.float32)   # the sample only spans the range: single precision halves its cost
    M, N = A.shape
    rank_max = min(M, N)
    rng = np.random.default_rng(seed)
    capacity = min(rank_max, 4 * max(1, int(block)))
    Q, B, G = np.empty((M, capacity)), np.empty((capacity, N)), np.zeros((0, 0))
    l = 0                                            # columns of the basis so far
    while True:
        b = min(max(1, int(block)), rank_max - l)
        if l + b > capacity:                         # the buffers grow geometrically: a block is copied O(1) times
            capacity = min(rank_max, max(2 * capacity, l + b))
            Q = np.hstack([Q[:, :l], np.empty((M, capacity - l))])
            B = np.vstack([B[:l], np.empty((capacity - l, N))])
        Yb = A32 @ rng.standard_normal((N, b)).astype(np.float32)
        Yb = (A32 @ (A32.T @ Yb)).astype(float)      # one power step: sharper subspace for a slow tail
        Q_old = Q[:, :l]
        for _ in range(2):                           # block Gram-Schmidt against the basis so far, twice
            Yb -= Q_old @ (Q_old.T @ Yb)
        Qb = np.linalg.qr(Yb)[0]
        Bb = Qb.T @ A
        Q[:, l:l + b], B[l:l + b] = Qb, Bb
        if tol >= GRAM_RESOLUTION:                   # squared singular values of B from its Gram matrix, grown
            cross = B[:l] @ Bb.T
            G = np.block([[G, cross], [cross.T, Bb @ Bb.T]])
            s = np.sqrt(np.maximum(np.linalg.eigvalsh(G)[::-1], 0.0))
        else:                                        # below its resolution: the SVD of B itself
            s = np.linalg.svd(B[:l + b], compute_uv=False)
        l += b
        below = np.count_nonzero(s <= tol * s[0])
        if below >= oversampling or l >= rank_max:
            break
    k = max(1, int(np.count_nonzero(s > tol * s[0])))
    if tol >= GRAM_RESOLUTION:
        # B = Y S X^T with G = X S^2 X^T: the right singular vectors are X^T B / s, without B's own SVD (a third
        # of the cost at rank 600); one QR makes them orthonormal to rounding (the kept ones carry the Gram
        # matrix's error, about 1e-16 s_max^2 / s_k^2 <= 1e-4 relative, only within the kept span)
        X = np.linalg.eigh(G)[1][:, ::-1][:, :k]     # the eigenvectors once, of the last Gram matrix
        Vt = np.linalg.qr(((X / s[:k]).T @ B[:l]).T)[0].T
        return Vt, s[:k]
    _, s, Vt = np.linalg.svd(B[:l], full_matrices=False)
    return Vt[:k], s[:k]
