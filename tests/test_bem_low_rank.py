"""The coupling's dominant right singular vectors (:mod:`electrosense.bem.low_rank`): an orthonormal basis that
carries the matrix to its tolerance, the same from the Gram matrix's eigenvectors as from the sample's SVD."""
import numpy as np
import pytest

from electrosense.bem.low_rank import GRAM_RESOLUTION, right_singular_vectors


@pytest.fixture(scope="module")
def graded():
    """900 x 500 with singular values from 1 down to 1e-9, geometrically: a slow tail like a coupling block's."""
    rng = np.random.default_rng(2)
    U = np.linalg.qr(rng.standard_normal((900, 500)))[0]
    V = np.linalg.qr(rng.standard_normal((500, 500)))[0]
    s = 10.0 ** -np.linspace(0, 9, 500)
    return (U * s) @ V.T, s


@pytest.mark.parametrize("tol, left_out", [(1e-5, 1e-4), (1e-6, 1e-5), (1e-10, 1e-8)])
def test_the_kept_span_carries_the_matrix_to_its_tolerance(graded, tol, left_out):
    A, s = graded
    Vt, s_kept = right_singular_vectors(A, tol)
    assert np.abs(Vt @ Vt.T - np.eye(len(Vt))).max() < 1e-12
    # the single-precision power step leaves a few times the tolerance out (the module's note; 1e-8 at most far
    # below it), and the kept count within a tenth of the exact one
    assert np.linalg.norm(A - A @ Vt.T @ Vt, 2) < left_out * s[0]
    assert 0.9 * np.count_nonzero(s > tol) <= len(Vt) <= np.count_nonzero(s > tol)
    assert np.all(np.diff(s_kept) <= 0) and s_kept[-1] > tol * s_kept[0]


def test_the_gram_matrix_and_the_svd_give_one_span(graded):
    """At the Gram matrix's resolution the vectors come from its eigenvectors, just below it from B's SVD: the
    same sample (one seed), so the same leading directions."""
    A, _ = graded
    Vt_gram, s_gram = right_singular_vectors(A, GRAM_RESOLUTION)
    Vt_svd, s_svd = right_singular_vectors(A, 0.999 * GRAM_RESOLUTION)
    k = 150   # singular values down to about 1e-3: well inside both
    P_gram, P_svd = Vt_gram[:k].T @ Vt_gram[:k], Vt_svd[:k].T @ Vt_svd[:k]
    assert np.linalg.norm(P_gram - P_svd, 2) < 1e-8
    np.testing.assert_allclose(s_gram[:k], s_svd[:k], rtol=1e-10)
