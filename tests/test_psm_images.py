"""Tank images: the paper's 8, the complete series and its convergence."""
import numpy as np
import pytest

from electrosense.meshes.tank import Tank
from electrosense.psm import (
    PlacementError,
    PolySphericalModel,
    conductance,
    image_sources,
    isolated_conductance,
    potential_coefficients,
)
from electrosense.psm.images import box_images

SIGMA = 0.0354
MODEL4 = PolySphericalModel.collinear([0.0072, 0.0074, 0.0074, 0.0072], [0.0785, 0.0769, 0.0785])
TANK = Tank((1.0, 0.9, 0.8), water_depth_m=0.6)  # floor at z = -0.4, free surface at z = 0.2


def _numpy_K(model, pose, tank, images):
    yaw = pose[3]
    Rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    X = model.centres_m @ Rz.T + pose[:3]
    img = images.apply(X)  # (K, n, 3)
    dR = np.einsum("k,kpq->pq", images.weights, 1 / np.linalg.norm(X[None, :, None] - img[:, None], axis=-1))
    R = potential_coefficients(model.radii_m, X)
    return isolated_conductance((R + dR) / (4 * np.pi * SIGMA), model.emitter)


@pytest.mark.parametrize("kind", ["paper8", "complete"])
def test_compiled_kernel_matches_a_plain_numpy_sum(kind):
    pose = np.array([0.2, -0.15, -0.05, 0.6])
    K = conductance(MODEL4, pose[None], SIGMA, TANK, images=kind, image_shells=4 if kind == "complete" else None).K_S[0]
    np.testing.assert_allclose(K, _numpy_K(MODEL4, pose, TANK, image_sources(TANK, kind, 4)), rtol=1e-12)


def test_paper8_images_lie_in_the_mid_plane_and_mirror_across_the_walls():
    imgs = image_sources(Tank((1.0, 1.0, 1.0)), "paper8")
    assert len(imgs) == 8
    p = imgs.apply(np.array([0.5, 0.1, 0.2]))  # a point on the wall x = +0.5 is its own image across it
    assert any(np.allclose(q, [0.5, 0.1, 0.2]) for q in p)
    assert np.all(imgs.signs[:, 2] == 1) and np.all(imgs.offsets_m[:, 2] == 0)


def test_complete_series_converges_like_one_over_shells_squared_and_richardson_removes_it():
    pose = np.array([[0.3, 0.2, -0.1, 0.7]])

    def K(shells, extrapolate):
        imgs = box_images(TANK, shells, extrapolate=extrapolate)
        return _numpy_K(MODEL4, pose[0], TANK, imgs)

    plain = {N: K(N, False) for N in (4, 8, 16)}
    d1 = np.abs(plain[8] - plain[4]).max()
    d2 = np.abs(plain[16] - plain[8]).max()
    assert 3.0 < d1 / d2 < 5.5  # ~ 1/N^2: doubling N divides the change by ~4
    scale = np.abs(plain[16]).max()
    rich8, rich16 = K(8, True), K(16, True)
    assert np.abs(rich16 - rich8).max() / scale < 1e-6  # the extrapolated series has settled
    assert np.abs(rich8 - rich16).max() < 0.25 * np.abs(plain[8] - rich16).max()


def test_auto_complete_series_states_its_error_below_the_tolerance():
    C = conductance(MODEL4, np.array([[0.3, 0.2, -0.1, 0.7], [0.0, 0.0, 0.0, 0.0]]), SIGMA, TANK, image_tolerance=1e-6)
    assert C.info["image_series_error"] < 1e-6
    ref = conductance(MODEL4, np.array([[0.3, 0.2, -0.1, 0.7]]), SIGMA, TANK, image_shells=24).K_S[0]
    assert np.abs(C.K_S[0] - ref).max() / np.abs(ref).max() < 1e-6


def test_half_turn_of_a_centred_tank_is_a_symmetry():
    tank = Tank((1.0, 1.0, 1.0), water_depth_m=0.7)
    a = conductance(MODEL4, np.array([[0.25, 0.1, -0.1, 0.3]]), SIGMA, tank).K_S
    b = conductance(MODEL4, np.array([[-0.25, -0.1, -0.1, 0.3 + np.pi]]), SIGMA, tank).K_S
    np.testing.assert_allclose(a, b, rtol=1e-9)


def test_one_near_wall_of_a_huge_tank_is_the_half_space_image():
    tank = Tank((20.0, 20.0, 20.0))
    pose = np.array([[10.0 - 0.15, 0.0, 0.0, 0.0]])
    K = conductance(MODEL4, pose, SIGMA, tank).K_S[0]
    wall = type(image_sources(tank, "none"))(np.array([[-1.0, 1, 1]]), np.array([[20.0, 0, 0]]))
    K_half = _numpy_K(MODEL4, pose[0], tank, wall)
    K_free = conductance(MODEL4, pose, SIGMA).K_S[0]
    assert np.abs(K - K_half).max() < 1e-3 * np.abs(K - K_free).max()


def test_walls_raise_the_resistance_towards_the_wall():
    poses = np.zeros((3, 4))
    poses[:, 0] = [0.0, 0.2, 0.35]
    for kind in ("paper8", "complete"):
        R = conductance(MODEL4, poses, SIGMA, Tank((1.0, 1.0, 1.0)), images=kind).resistance_ohm
        assert np.all(np.diff(R[:, 0]) > 0), kind


def test_sensor_outside_the_water_is_refused():
    with pytest.raises(PlacementError, match="wall_x\\+"):
        conductance(MODEL4, np.array([[0.0, 0, 0, 0], [0.45, 0, 0, 0]]), SIGMA, Tank((1.0, 1.0, 1.0)))
    with pytest.raises(PlacementError, match="free_surface"):
        conductance(MODEL4, np.array([[0.0, 0, 0.195, 0]]), SIGMA, TANK)
