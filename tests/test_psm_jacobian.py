"""Jacobian of the receiver currents with respect to the pose, against finite differences."""
import numpy as np
import pytest

from electrosense.meshes.objects import Sphere
from electrosense.meshes.sensor import preset
from electrosense.meshes.tank import Tank
from electrosense.psm import PolySphericalModel, conductance, receiver_current_jacobian

SIGMA = 0.0354
MODEL4 = PolySphericalModel.collinear([0.0072, 0.0074, 0.0074, 0.0072], [0.0785, 0.0769, 0.0785])
TANK = Tank((1.0, 1.0, 1.0), water_depth_m=0.8)


@pytest.mark.parametrize("images, objects", [
    ("paper8", ()),
    ("complete", ()),
    ("complete", (Sphere((0.1, 0.12, -0.1), "conducting", radius_m=0.02),)),
])
@pytest.mark.parametrize("method", ["analytic", "complex-step"])
def test_jacobian_matches_central_differences(images, objects, method):
    poses = np.array([[0.2, -0.1, -0.1, 0.4], [-0.3, 0.25, -0.1, 2.0]])
    J = receiver_current_jacobian(MODEL4, poses, SIGMA, TANK, images, objects, image_shells=8, method=method)
    h = 1e-5
    for j, col in enumerate((0, 1, 3)):
        dp = np.zeros(4)
        dp[col] = h
        Ip = conductance(MODEL4, poses + dp, SIGMA, TANK, images, objects, image_shells=8).receiver_currents_A()
        Im = conductance(MODEL4, poses - dp, SIGMA, TANK, images, objects, image_shells=8).receiver_currents_A()
        fd = (Ip - Im) / (2 * h)
        np.testing.assert_allclose(J[:, :, j], fd, rtol=1e-5, atol=1e-6 * np.abs(fd).max())


def test_jacobian_vanishes_in_unbounded_water_and_has_the_contract_shape():
    J = receiver_current_jacobian(MODEL4, np.array([[0.1, 0.2, 0.0, 1.0]] * 3), SIGMA)
    assert J.shape == (3, 3, 3)
    assert np.abs(J).max() < 1e-15


def test_analytic_and_complex_step_agree_to_round_off():
    poses = np.array([[0.25, 0.1, 0.0, 0.3], [-0.2, -0.3, 0.1, -1.0]])
    objs = (Sphere((0.0, 0.0, 0.2), 0.0, radius_m=0.03),)
    a = receiver_current_jacobian(MODEL4, poses, SIGMA, TANK, "complete", objs, contact_impedance_ohm_m2=0.01,
                                  sensor=preset("angels-4"))
    c = receiver_current_jacobian(MODEL4, poses, SIGMA, TANK, "complete", objs, contact_impedance_ohm_m2=0.01,
                                  sensor=preset("angels-4"), method="complex-step")
    np.testing.assert_allclose(a, c, rtol=1e-8, atol=1e-10 * np.abs(c).max())
