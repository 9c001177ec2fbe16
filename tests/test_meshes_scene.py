"""Scenes: every refusal names its parts; meshing a scene in the right frames."""
import numpy as np
import pytest

from electrosense.meshes import TANK_REGIONS, Box, Cylinder, Pose, Scene, Sphere, Tank, preset
from electrosense.meshes.quality import check_mesh
from electrosense.meshes.scene_mesh import SceneError, check_scene, scene_problems

SENSOR = preset("angels-4")  # 20 cm long, radius about 1.2 cm
TANK = Tank((1.0, 0.6, 0.5), water_depth_m=0.4)  # water: x +-0.5, y +-0.3, z -0.25..0.15


def scene(pose=(0, 0, 0, 0), objects=(), tank=TANK):
    return Scene(SENSOR, Pose(*pose), tank, tuple(objects))


def refusal(s) -> str:
    with pytest.raises(ValueError) as info:
        check_scene(s)
    assert isinstance(info.value, SceneError)
    return str(info.value)


def test_a_good_scene_passes():
    s = scene((0.1, 0.05, -0.05, 0.7), [Sphere((-0.2, 0.1, 0.0), radius_m=0.03), Box((0.2, -0.15, -0.1), size_m=(0.05, 0.05, 0.1)),
                                         Cylinder((-0.3, -0.2, -0.1), radius_m=0.02, height_m=0.2)])
    assert check_scene(s) is s
    assert scene_problems(scene(tank=None)) == []


@pytest.mark.parametrize(
    "pose, boundary",
    [
        ((0.0, 0.0, 0.145, 0.0), "free_surface"),  # the centre is in the water, the body is not
        ((0.0, 0.0, -0.245, 0.0), "floor"),
        ((0.45, 0.0, 0.0, 0.0), "wall_x+"),  # the head's tip crosses: 0.45 + 0.1 > 0.5
        ((0.0, -0.25, 0.0, -np.pi / 2), "wall_y-"),
        ((-0.42, 0.0, 0.0, np.pi), "wall_x-"),
    ],
)
def test_sensor_out_of_the_water_names_the_boundary(pose, boundary):
    msg = refusal(scene(pose))
    assert "the sensor" in msg and f"out of the water across the {boundary}" in msg


def test_the_capsule_not_the_centre_decides():
    # yawed 90 deg the sensor fits across x (its length is along y) but not across y
    assert scene_problems(scene((0.45, 0.0, 0.0, np.pi / 2))) == []
    assert "wall_y+" in refusal(scene((0.0, 0.22, 0.0, np.pi / 2)))
    # exactly touching the free surface is refused too
    assert "touches the free_surface" in refusal(scene((0.0, 0.0, TANK.free_surface_z_m - SENSOR.radius_m, 0.0)))


def test_object_out_of_the_water_or_touching_a_boundary():
    msg = refusal(scene(objects=[Sphere((0.0, 0.2, 0.14), radius_m=0.03, name="float")]))
    assert "object_1 (sphere 'float') is out of the water across the free_surface" in msg
    msg = refusal(scene(objects=[Sphere((0, 0.2, 0), radius_m=0.01), Box((0.3, 0.0, -0.2), size_m=(0.1, 0.1, 0.1))]))
    assert "object_2 (box) touches the floor" in msg and "object_1" not in msg
    msg = refusal(scene(objects=[Cylinder((0.0, 0.29, -0.1), radius_m=0.02, height_m=0.1)]))
    assert "object_1 (cylinder) is out of the water across the wall_y+" in msg


@pytest.mark.parametrize(
    "obj",
    [
        Sphere((0.0, 0.025, 0.0), radius_m=0.02),  # beside the middle
        Sphere((0.115, 0.0, 0.0), radius_m=0.02),  # beyond the head's tip, touching its hemisphere
        Box((0.0, 0.0, 0.03), size_m=(0.05, 0.05, 0.05), yaw_rad=0.3),  # just over it
        Cylinder((-0.05, 0.0, 0.0), radius_m=0.01, height_m=0.2),  # a pole through it
        Cylinder((0.0, 0.0, -0.06), radius_m=0.05, height_m=0.101),  # a disc under it, reaching up to z=-0.0095
    ],
)
def test_object_intersecting_the_sensor(obj):
    assert "object_1" in refusal(scene(objects=[obj])) and "the sensor" in refusal(scene(objects=[obj]))


@pytest.mark.parametrize(
    "obj",
    [
        Sphere((0.0, 0.035, 0.0), radius_m=0.02),
        Sphere((0.125, 0.0, 0.0), radius_m=0.02),
        Sphere((0.099, 0.0095, 0.0), radius_m=0.002),  # by the rounded tip: clear of the capsule, not of its box
        Cylinder((0.0, 0.0, -0.07), radius_m=0.05, height_m=0.1),
    ],
)
def test_objects_near_but_clear_of_the_sensor_pass(obj):
    assert scene_problems(scene(objects=[obj])) == []


def test_objects_intersecting_each_other():
    a = Box((0.2, 0.1, -0.1), size_m=(0.1, 0.1, 0.1))
    b = Cylinder((0.26, 0.1, -0.1), radius_m=0.02, height_m=0.05)  # pokes into the box
    c = Sphere((0.3, -0.2, 0.0), radius_m=0.02)
    d = Sphere((0.33, -0.2, 0.0), radius_m=0.02)
    msg = refusal(scene(objects=[a, b, c, d]))
    assert "object_1 (box) and object_2 (cylinder) intersect" in msg
    assert "object_3 (sphere) and object_4 (sphere) intersect" in msg
    assert scene_problems(scene(objects=[a, c])) == []


def test_mesh_scene_frames_regions_and_grading():
    pytest.importorskip("electrosense.meshes.sensor_mesh")
    from electrosense.meshes.scene_mesh import mesh_scene

    pose = Pose(0.2, -0.25, -0.05, 0.3)  # 2 cm from the wall y-
    s = scene(tuple(pose.as_array()), [Sphere((-0.1, 0.1, 0.0), radius_m=0.03)])
    sm = mesh_scene(s)
    # the sensor stays in its own frame, centred on the origin along x
    assert np.allclose(sm.sensor.vertices_m.mean(axis=0), 0.0, atol=2e-3)
    assert np.ptp(sm.sensor.vertices_m[:, 0]) == pytest.approx(SENSOR.length_m, rel=1e-3)
    assert np.allclose(sm.sensor_in_tank.vertices_m, pose.to_tank(sm.sensor.vertices_m))
    combined = sm.combined()
    assert combined.region_names == ("sensor", *TANK_REGIONS, "object_1")
    assert combined.n_triangles == sm.n_triangles
    q = check_mesh(combined)
    assert q.n_shells == 3 and q.is_outward
    assert set(np.unique(combined.electrode[combined.region_mask("sensor")])) == {0, 1, 2, 3, 4}
    assert np.all(combined.electrode[~combined.region_mask("sensor")] == 0)
    # the tank is finer on the wall next to the sensor than on the far ones
    tank = sm.tank
    size = np.sqrt(tank.areas_m2)
    assert size[tank.region_mask("wall_y-")].min() < 0.5 * size[tank.region_mask("wall_y+")].min()


def test_mesh_scene_refuses_before_meshing_and_allows_unbounded_water():
    pytest.importorskip("electrosense.meshes.sensor_mesh")
    from electrosense.meshes.scene_mesh import mesh_scene

    with pytest.raises(ValueError, match="free_surface"):
        mesh_scene(scene((0, 0, 0.15, 0)))
    sm = mesh_scene(scene(tank=None))
    assert sm.tank is None and sm.combined().region_names == ("sensor",)


def test_trajectory_focus_follows_each_pose_heading():
    from electrosense.meshes.scene_mesh import trajectory_focus_m

    poses = np.array([[0.0, 0.0, -0.1, 0.0], [0.2, 0.1, -0.1, np.pi / 2]])
    pts = trajectory_focus_m(SENSOR, poses, n_per_pose=3).reshape(2, 3, 3)
    half_core = 0.5 * SENSOR.length_m - SENSOR.radius_m
    assert np.allclose(pts[0], [[-half_core, 0, -0.1], [0, 0, -0.1], [half_core, 0, -0.1]])
    assert np.allclose(pts[1], [[0.2, 0.1 - half_core, -0.1], [0.2, 0.1, -0.1], [0.2, 0.1 + half_core, -0.1]])
