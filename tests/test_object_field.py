"""The object model's field (dipole and quadrupole from the BEM's own field, the walls' first reflections) against
the BEM with the ball meshed: in a round tank the curved wall reflects in its tangent plane."""
from __future__ import annotations

import numpy as np
import pytest

from electrosense.meshes import preset
from electrosense.meshes.cylinder_tank import CylinderTank
from electrosense.meshes.objects import Sphere
from electrosense.meshes.tank import Tank
from electrosense.validation.diagnosis.object_field import sensor_object_field, wall_reflections
from electrosense.validation.simulation.models import simulate

EDGE_M = 0.006


@pytest.fixture(scope="module")
def beside_the_curved_wall():
    """angels-2 along the wall of a round tank (radius 0.2 m) at three azimuths, 0, 22.5 and 45 degrees, a
    conducting ball (radius 12 mm) between it and the wall, 8 mm from the wall and 26 mm from the sensor: the BEM's
    change of K with the ball meshed (other code than the field's), the same at every azimuth but for its mesh."""
    sensor = preset("angels-2")
    tank = CylinderTank(radius_m=0.2, height_m=0.2)
    out = []
    for azimuth in (0.0, np.pi / 8, np.pi / 4):
        radial = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
        ball = Sphere(tuple(0.18 * radial), float("inf"), radius_m=0.012)
        pose = np.r_[0.13 * radial[:2], 0.0, azimuth + np.pi / 2][None]
        K = [simulate("bem", sensor, pose, tank, 1.0, objects=objects, edge_length_m=EDGE_M).K_S[0]
             for objects in ((), (ball,))]
        out.append((ball, pose, K[1] - K[0]))
    return sensor, tank, out


def test_the_curved_wall_reflects_the_field_in_its_tangent_plane(beside_the_curved_wall):
    """The model in a round tank is the same at every azimuth, as the physics is (the round tank's bounding box's
    reflections, which it took before, made it 22 % apart between 0 and 45 degrees here), and within 30 % of the
    BEM (the model's own deficit: 16-22 % low in unbounded water for this ball; first reflections only)."""
    sensor, tank, cases = beside_the_curved_wall
    field = sensor_object_field(sensor, 1.0, EDGE_M)
    box = Tank((0.4, 0.4, 0.2))     # the round tank's bounding box
    assert np.allclose(box.water_bounds_m, tank.water_bounds_m)
    e = sensor.emitter - 1
    r = 1 - e
    tangent = np.array([field(pose, tank, (ball,))[0, r, e] / dK[r, e] for ball, pose, dK in cases])
    bounding = np.array([field(pose, box, (ball,))[0, r, e] / dK[r, e] for ball, pose, dK in cases])
    print(f"model / BEM at 0, 22.5, 45 degrees: tangent plane {tangent.round(3)}, bounding box {bounding.round(3)}")
    spread = np.ptp(tangent) / tangent.mean()
    assert spread < 0.03 and np.ptp(bounding) / bounding.mean() > 3 * spread
    assert np.all(np.abs(tangent - 1.0) < 0.3)


def test_the_reflections_of_a_round_tank_are_mirror_images():
    """Each reflection is an involution with its matrix a reflection (det -1), the wall's at the radius' meeting."""
    tank = CylinderTank(radius_m=0.3, height_m=0.4, water_depth_m=0.35)
    rng = np.random.default_rng(5)
    p = np.column_stack([rng.uniform(-0.2, 0.2, (20, 2)), rng.uniform(-0.15, 0.1, 20)])
    (q0, M0), *mirrors = wall_reflections(tank, p)
    assert np.allclose(q0, p) and np.allclose(M0, np.eye(3)) and len(mirrors) == 3
    wall, floor, surface = mirrors
    rho_q = np.hypot(wall[0][:, 0], wall[0][:, 1])
    assert np.allclose(rho_q + np.hypot(p[:, 0], p[:, 1]), 0.6)        # rho -> 2 R - rho
    assert np.allclose(np.linalg.det(wall[1]), -1.0) and np.allclose(wall[1] @ wall[1], np.eye(3))
    assert np.allclose(floor[0][:, 2] + p[:, 2], 2 * tank.floor_z_m)
    assert np.allclose(surface[0][:, 2] + p[:, 2], 2 * tank.free_surface_z_m)
