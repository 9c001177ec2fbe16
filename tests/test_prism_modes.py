"""Prism scenes by cosine modes: the 2-D layers and the wall responses against closed forms (a disc, an annulus
with an insulating or a floating conducting core, any mode), the complete electrode model's limits."""
import numpy as np
import pytest
from scipy.special import iv, ivp, kv, kvp

from electrosense.bem.helmholtz2d import layer_matrices_2d
from electrosense.bem.prism_modes import PrismModel, electrode_cells, solve_prism_scene, wall_responses
from electrosense.meshes.prism_scene import Prism, PrismScene, WallPatch, polygons_from_mask, ring_patches
from electrosense.meshes.section_mesh import mesh_section


@pytest.mark.parametrize("k", [0.0, 30.0, 400.0])
def test_disc_neumann_to_dirichlet(k):
    R, N = 0.1, 256
    t = np.linspace(0, 2 * np.pi, N + 1)[:-1]
    p = R * np.stack([np.cos(t), np.sin(t)], 1)
    a, b = p, np.roll(p, -1, 0)
    mid = 0.5 * (a + b)
    th = np.arctan2(mid[:, 1], mid[:, 0])
    S, D = layer_matrices_2d(mid, a, b, k, own=np.arange(N))
    H = D + 0.5 * np.eye(N)
    for m in (1, 4):
        q = np.cos(m * th)
        if k == 0:
            u = np.linalg.lstsq(H, S @ q, rcond=None)[0]
            u -= u.mean()
            lam = m / R
        else:
            u = np.linalg.solve(H, S @ q)
            lam = k * ivp(m, k * R) / iv(m, k * R)
        assert np.abs(u - q / lam).max() < 3e-3 * np.abs(q / lam).max()


def _annulus_lambda(m, k, R, rho, core):
    """d phi_m / dr over phi_m at r = R for the annulus rho < r < R (core: 'insulating' or 'conducting')."""
    if k == 0:
        q = (rho / R) ** (2 * m)
        return m / R * ((1 - q) / (1 + q) if core == "insulating" else (1 + q) / (1 - q))
    f, fp = (lambda r: iv(m, k * r)), (lambda r: k * ivp(m, k * r))
    g, gp = (lambda r: kv(m, k * r)), (lambda r: k * kvp(m, k * r))
    A, B = (gp(rho), -fp(rho)) if core == "insulating" else (g(rho), -f(rho))
    return (A * fp(R) + B * gp(R)) / (A * f(R) + B * g(R))


@pytest.mark.parametrize("core", ["none", "insulating", "conducting"])
@pytest.mark.parametrize("mode", [0, 3])
def test_wall_responses_against_the_annulus(core, mode):
    """Uniform current on two opposite electrodes (the gap model): their potential difference from the modal
    responses against the Fourier series of a disc or an annulus with a concentric core."""
    R, rho, depth = 0.1, 0.04, 0.05
    w = np.radians(20.0)
    scene = PrismScene(R, depth, ring_patches(2, 0.0, 20.0, 0.0, depth))
    if core != "none":
        t = np.linspace(0, 2 * np.pi, 181)[:-1]
        poly = rho * np.stack([np.cos(t), np.sin(t)], 1)
        scene = PrismScene(R, depth, scene.electrodes, (Prism(poly, np.inf if core == "conducting" else 0.0),))
    mesh = mesh_section(scene, segments_per_electrode=24, segments_per_gap=24, max_wall_segment_m=0.004,
                        object_spacing_m=0.002)
    resp = wall_responses(mesh, depth, mode + 1, conducting=(core == "conducting",))
    g, seg = resp["g"][mode], resp["seg"]
    L = mesh.lengths[seg]
    lab = mesh.electrode[seg]
    j = np.where(lab == 1, 1.0, -1.0)                     # unit current density in on 1, out on 2
    u = g @ j
    V = [np.sum(u[lab == e] * L[lab == e]) / np.sum(L[lab == e]) for e in (1, 2)]
    k = mode * np.pi / depth
    # Fourier series: flux j(theta) = +1 on |theta| < w/2, -1 on |theta - pi| < w/2; odd m only survive
    series = 0.0
    for m in range(1, 4001 if mode == 0 else 151, 2):          # terms fall as 1/m^3
        c = 4 / (np.pi * m) * np.sin(m * w / 2)                     # cos-coefficient of the flux
        lam = (m / R if k == 0 else k * ivp(m, k * R) / iv(m, k * R)) if core == "none" else \
            _annulus_lambda(m, k, R, rho, core)
        avg = np.sin(m * w / 2) / (m * w / 2)                        # mean of cos(m theta) over the electrode
        series += 2 * c * avg / lam                                  # electrode 2 sees -avg (m odd)
    assert V[0] - V[1] == pytest.approx(series, rel=5e-3)


def test_two_d_limit_and_reciprocity():
    s = PrismScene(0.1, 0.03, ring_patches(8, 0.0, 15.0, 0.0, 0.03))
    s2 = PrismScene(0.1, 0.03, ring_patches(8, 0.0, 15.0, 0.005, 0.02))
    Z = solve_prism_scene(s, 1.0, 1e-3, n_modes=3).Z_ohm
    Z2 = solve_prism_scene(s2, 1.0, 1e-3, n_modes=30).Z_ohm
    P = np.eye(8) - 1 / 8
    for z in (Z, Z2):
        c = P @ z @ P
        assert np.abs(c - c.T).max() < 2e-3 * np.abs(c).max()      # reciprocity of the collocation
    r = lambda z: z[0, 0] + z[4, 4] - z[0, 4] - z[4, 0]               # noqa: E731
    assert r(Z2) > r(Z)                                              # shorter electrodes: more spreading resistance


def test_metal_behind_a_huge_contact_is_plastic_and_objects_change_the_impedance():
    t = np.linspace(0, 2 * np.pi, 41)[:-1]
    poly = 0.03 * np.stack([np.cos(t), np.sin(t)], 1) + [0.03, 0.0]
    ring = ring_patches(8, 0.0, 15.0, 0.0, 0.01)
    def Z(objs, zeta=()):
        m = PrismModel(PrismScene(0.1, 0.02, ring, objs), n_modes=8, object_zeta_m=zeta or None)
        return m.impedance(1e-3)
    empty, plastic = Z(()), Z((Prism(poly, 0.0),))
    metal, coated = Z((Prism(poly, np.inf),)), Z((Prism(poly, np.inf),), (1e4,))
    tr = lambda z: z[0, 0] - z[0, 4] - z[4, 0] + z[4, 4]              # noqa: E731
    assert tr(plastic) > tr(empty) > tr(metal)
    assert tr(coated) == pytest.approx(tr(plastic), rel=1e-3)


def test_mask_polygons_and_scene_problems():
    m = np.zeros((40, 40), bool)
    m[10:30, 5:15] = True
    m[15:20, 8:11] = False                     # a hole: filled (water inside a prism carries no current)
    m[2:5, 30:33] = True
    x = np.arange(40) + 0.5
    polys = polygons_from_mask(m, x, 40 - x)
    areas = sorted(abs(0.5 * np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1])) for p in polys)
    assert len(polys) == 2 and areas[1] == pytest.approx(200, rel=0.05) and areas[0] == pytest.approx(9, rel=0.35)
    scene = PrismScene(0.1, 0.02, [WallPatch(0.0, 0.3, 0.0, 0.03), WallPatch(0.2, 0.5, 0.0, 0.01)],
                       (Prism(np.array([[0.0, 0.0], [0.2, 0.0], [0.0, 0.02]])),))
    text = " ".join(scene.problems())
    assert "outside the water" in text and "overlap" in text and "closer than" in text
    with pytest.raises(ValueError, match="prism scene"):
        PrismModel(scene)


def test_cells_cover_every_electrode():
    s = PrismScene(0.1, 0.04, ring_patches(4, 10.0, 20.0, 0.01, 0.03))
    mesh = mesh_section(s, 5, 3)
    resp = wall_responses(mesh, 0.04, 2)
    cells = electrode_cells(s, mesh, resp["seg"], 4)
    area = np.bincount(cells.electrode, cells.area)
    assert np.allclose(area, area[0]) and area[0] == pytest.approx(0.02 * np.radians(20.0) * 0.1, rel=2e-3)


def test_current_patterns_through_K_and_through_Z_agree():
    from electrosense.bem.protocol import pattern_voltages_V
    from electrosense.validation.comparison.ktc_model import volts

    sol = solve_prism_scene(PrismScene(0.1, 0.03, ring_patches(6, 0.0, 20.0, 0.0, 0.02)), 0.5, 2e-3, n_modes=10)
    rng = np.random.default_rng(0)
    inj = rng.standard_normal((6, 4))
    inj -= inj.mean(axis=0)
    mp = np.eye(6)[:, :5] - np.eye(6)[:, 1:6]
    assert np.allclose(pattern_voltages_V(sol.K_S, inj, mp), volts(sol.Z_ohm, inj, mp), rtol=1e-8, atol=1e-10)
