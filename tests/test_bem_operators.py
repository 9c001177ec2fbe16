"""Closed-form triangle integrals and the layer operators."""
import numpy as np
import pytest
import trimesh

from electrosense.bem.operators import double_layer, layer_matrices, single_layer
from electrosense.bem.quadrature import DUNAVANT_5, rule_points
from electrosense.bem.triangle_integrals import inverse_distance_integrals, solid_angles

TRI = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.3, 0.8, 0.0]]])


def _subdivided_quadrature(x, tri, f, levels=6):
    """Reference: the degree-5 rule on 4^levels sub-triangles."""
    tris = tri.copy()
    for _ in range(levels):
        a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
        ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
        tris = np.concatenate([np.stack(t, axis=1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    pts, w = rule_points(tris, DUNAVANT_5)
    return float(np.sum(w * f(x, pts)))


@pytest.mark.parametrize("x", [[0.2, 0.3, 0.5], [0.2, 0.3, 0.05], [2.0, 1.0, 0.3], [-0.5, 0.2, 0.0], [0.4, 0.2, -0.2]])
def test_inverse_distance_integral_matches_quadrature(x):
    x = np.array(x)
    ref = _subdivided_quadrature(x, TRI, lambda x, p: 1 / np.linalg.norm(p - x, axis=-1))
    assert inverse_distance_integrals(x, TRI)[0, 0] == pytest.approx(ref, rel=1e-6)


@pytest.mark.parametrize("x", [[0.2, 0.3, 0.5], [0.2, 0.3, 0.05], [2.0, 1.0, 0.3], [0.4, 0.2, -0.2]])
def test_solid_angle_matches_quadrature_and_sign(x):
    x = np.array(x)
    n = np.array([0.0, 0.0, 1.0])
    ref = _subdivided_quadrature(x, TRI, lambda x, p: ((p - x) @ n) / np.linalg.norm(p - x, axis=-1) ** 3)
    omega = solid_angles(x, TRI)[0, 0]
    assert omega == pytest.approx(ref, rel=1e-5)
    assert np.sign(omega) == -np.sign(x[2])   # negative when the normal points towards x


def test_self_integral_of_an_equilateral_triangle():
    # int over an equilateral triangle (side s) of 1/r from its centroid = s * sqrt(3) * ln(2 + sqrt 3) / ... (closed form)
    s = 1.0
    tri = np.array([[[0, 0, 0], [s, 0, 0], [s / 2, s * np.sqrt(3) / 2, 0]]])
    centroid = tri[0].mean(axis=0)
    # each edge at distance d = s/(2 sqrt 3) subtends half-width s/2: 3 * 2 * d * asinh((s/2)/d)
    d = s / (2 * np.sqrt(3))
    assert inverse_distance_integrals(centroid, tri)[0, 0] == pytest.approx(6 * d * np.arcsinh(s / 2 / d), rel=1e-12)


def test_solid_angles_of_a_closed_surface():
    s = trimesh.creation.icosphere(2)
    tri = s.vertices[s.faces]
    inside, outside = np.zeros((1, 3)), np.array([[3.0, 0.2, 0.1]])
    assert solid_angles(inside, tri).sum() == pytest.approx(4 * np.pi, rel=1e-12)
    assert solid_angles(outside, tri).sum() == pytest.approx(0.0, abs=1e-12)
    # on the surface (principal value): rows of the double layer sum to -1/2 exactly
    D = double_layer(tri.mean(axis=1), tri, own=np.arange(len(tri)))
    np.testing.assert_allclose(D.sum(axis=1), -0.5, atol=1e-12)


def test_single_layer_of_a_uniform_sphere_density():
    # potential of a unit density on a sphere of radius 1: int G dS = 1 on the surface, 1/|x| outside
    s = trimesh.creation.icosphere(3)
    tri = s.vertices[s.faces]
    S = single_layer(tri.mean(axis=1), tri, own=np.arange(len(tri)))
    assert S.sum(axis=1).mean() == pytest.approx(1.0, rel=3e-3)
    far = single_layer(np.array([[0.0, 0.0, 3.0]]), tri)
    assert far.sum() == pytest.approx(s.area / (4 * np.pi) / 3.0, rel=1e-4)


def test_quadrature_tiers_agree_with_exact_integration():
    s = trimesh.creation.icosphere(3)
    tri = s.vertices[s.faces]
    pts = tri.mean(axis=1)
    S, _ = layer_matrices(pts, tri, own=np.arange(len(tri)))
    S_exact, _ = layer_matrices(pts, tri, own=np.arange(len(tri)), near=1e9)
    assert np.abs(S - S_exact).max() < 5e-5 * np.abs(S_exact).max()   # far below the O(h^2) discretisation error
    assert np.abs((S - S_exact).sum(axis=1)).max() < 1e-4 * S_exact.sum(axis=1).min()
