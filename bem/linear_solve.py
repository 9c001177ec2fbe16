"""Dense linear solves of BEM systems: LU factors that refuse singular systems, mixed-precision refinement.

Example
-------
>>> import numpy as np
>>> A = np.array([[4.0, 1.0], [1.0, 3.0]])
>>> X, rcond, refinements = solve_dense(A.copy(), np.array([[1.0], [2.0]]))
>>> bool(np.allclose(A @ X, [[1.0], [2.0]]))
True
"""
from __future__ import annotations

import warnings

import numpy as np
import scipy.linalg

from electrosense.bem.boundary_conditions import BoundaryError

__all__ = ["SingularSystemError", "factorise", "solve_dense", "solve_refined", "refine"]


class SingularSystemError(BoundaryError):
    """The BEM system is singular (or numerically so)."""


def factorise(matrix: np.ndarray, what: str = "BEM system"):
    """LU factors of ``matrix`` (overwritten), refusing singular systems with a clear message."""
    norm1 = np.linalg.norm(matrix, 1)
    with warnings.catch_warnings():
        warnings.simplefilter("error", scipy.linalg.LinAlgWarning)
        try:
            lu, piv = scipy.linalg.lu_factor(matrix, overwrite_a=True, check_finite=False)
        except (scipy.linalg.LinAlgWarning, np.linalg.LinAlgError) as exc:
            raise SingularSystemError(f"the {what} is singular ({exc}); is every part closed and every "
                                      "electrode separated from the others?") from None
    gecon, = scipy.linalg.get_lapack_funcs(("gecon",), (lu,))
    rcond, info = gecon(lu, norm1, norm="1")
    if not np.isfinite(rcond) or rcond < 1e-14:
        raise SingularSystemError(f"the {what} is numerically singular (reciprocal condition number {rcond:.1e}); "
                                  "check for overlapping or touching parts and degenerate triangles")
    return lu, piv, float(rcond)


def solve_dense(matrix: np.ndarray, rhs: np.ndarray, what: str = "BEM system", precision: str = "mixed",
                refinement_tol: float = 1e-12, max_refinements: int = 6):
    """Solve ``matrix @ X = rhs``; returns ``(X, rcond, refinements)``.

    ``precision="mixed"``: LU in float32 (half the memory traffic and twice
    the speed of float64), then iterative refinement with float64 residuals
    until the relative residual is below ``refinement_tol`` (the answer has
    float64 accuracy for any reasonably conditioned BEM system).
    ``"double"``: LU in float64, factorising ``matrix`` in place. A complex
    system is solved the same way (complex64 LU, complex128 refinement).
    """
    if precision == "double":
        lu, piv, rcond = factorise(matrix, what)
        return scipy.linalg.lu_solve((lu, piv), rhs, check_finite=False), rcond, 0
    if precision != "mixed":
        raise ValueError(f"precision must be 'mixed' or 'double', got {precision!r}")
    low = np.complex64 if np.iscomplexobj(matrix) else np.float32
    lu, piv, rcond = factorise(matrix.astype(low), what)
    if rcond < 1e-6:  # too ill-conditioned for a float32 factorisation to converge quickly
        X, rcond, _ = solve_dense(matrix, rhs, what, "double")
        return X, rcond, 0
    X, refinements = solve_refined(matrix, rhs, (lu, piv), what, refinement_tol, max_refinements)
    return X, rcond, refinements


def solve_refined(matrix: np.ndarray, rhs: np.ndarray, factors, what: str = "BEM system",
                  refinement_tol: float = 1e-12, max_refinements: int = 6):
    """Solve ``matrix @ X = rhs`` (float64) with low-precision LU ``factors`` of ``matrix`` and iterative
    refinement on float64 residuals; returns ``(X, refinements)``."""
    lu, piv = factors
    full = np.result_type(matrix.dtype, rhs.dtype, np.float64)   # float64, or complex128 for a complex system

    def low_precision_solve(R):
        return scipy.linalg.lu_solve((lu, piv), R.astype(lu.dtype), check_finite=False).astype(full)

    return refine(lambda X: matrix @ X, rhs, low_precision_solve(rhs), low_precision_solve, what, refinement_tol,
                  max_refinements)


def refine(apply, rhs: np.ndarray, X: np.ndarray, approximate_inverse, what: str = "BEM system",
           refinement_tol: float = 1e-12, max_refinements: int = 6):
    """Iterative refinement of ``X`` towards ``apply(X) = rhs``: float64 residuals, each correction by the
    low-precision ``approximate_inverse`` (a factorisation in float32, or a Woodbury formula on one), until the
    relative residual is below ``refinement_tol``; returns ``(X, refinements)``. Refuses (:class:`SingularSystemError`)
    a system whose refinement does not converge: it is close to singular.

    >>> A = np.array([[4.0, 1.0], [1.0, 3.0]]); b = np.array([1.0, 2.0])
    >>> rough = lambda r: np.linalg.solve(A + 0.01, r)     # an inverse good to about 1e-2
    >>> X, k = refine(lambda x: A @ x, b, rough(b), rough)
    >>> bool(np.allclose(A @ X, b, rtol=0, atol=1e-12)), k
    (True, 5)
    """
    norm_rhs = np.linalg.norm(rhs)
    for k in range(1, max_refinements + 1):
        R = rhs - apply(X)
        if np.linalg.norm(R) <= refinement_tol * norm_rhs:
            return X, k - 1
        X = X + approximate_inverse(R)
    residual = np.linalg.norm(rhs - apply(X)) / norm_rhs
    if residual > 1e3 * refinement_tol:
        raise SingularSystemError(f"the {what} did not converge under iterative refinement "
                                  f"(residual {residual:.1e}); it is close to singular")
    return X, max_refinements
