"""Scene files: the example, round trips, relative sensor files, refusals, command-line overrides."""
from pathlib import Path

import pytest

from electrosense.meshes import Pose, Tank, preset, save_sensor
from electrosense.meshes.objects import Cylinder, Sphere
from electrosense.meshes.scene_file import apply_overrides, load_scene, load_scene_settings, save_scene
from electrosense.meshes.scene_mesh import check_scene

EXAMPLE = Path(__file__).resolve().parents[1] / "validation" / "data" / "example_scene.toml"


def test_the_example_scene_loads_and_is_valid():
    scene = load_scene(EXAMPLE)
    check_scene(scene)
    assert scene.sensor.name == "angels-4" and scene.sensor.emitter == 4
    assert scene.tank == Tank((1.0, 1.0, 1.0), 0.8)
    assert [type(o) for o in scene.objects] == [Sphere, Cylinder]
    assert scene.objects[0].is_conducting and scene.objects[1].is_insulating
    assert load_scene_settings(EXAMPLE) == {"water": {"sigma_S_per_m": 0.0354}}


def test_round_trip(tmp_path):
    scene = load_scene(EXAMPLE)
    scene = apply_overrides(scene, pose=Pose(0.1, -0.2, 0.0, 1.25),
                            objects=scene.objects + (Sphere((0.3, 0.3, 0.0), radius_m=0.01, conductivity_S_per_m=0.25),))
    path = save_scene(scene, tmp_path / "s.toml", settings={"water": {"sigma_S_per_m": 0.05}})
    assert load_scene(path) == scene
    assert load_scene_settings(path)["water"]["sigma_S_per_m"] == 0.05


def test_sensor_file_relative_to_the_scene_file(tmp_path):
    (tmp_path / "sensors").mkdir()
    mine = preset("angels-2")
    save_sensor(mine, tmp_path / "sensors" / "mine.json")
    (tmp_path / "bench.toml").write_text('[sensor]\nfile = "sensors/mine.json"\npose = [0, 0, 0, 0]\n')
    scene = load_scene(tmp_path / "bench.toml")
    assert scene.sensor == mine and scene.tank is None  # no [tank]: unbounded water


@pytest.mark.parametrize(
    "text, message",
    [
        ('[sensor]\npreset = "angels-4"\npose = [0, 0, 0]\n', r"\[sensor\] pose must be 4"),
        ('[sensor]\npreset = "angels-4"\nposition = [0, 0, 0, 0]\n', "unknown key.*position"),
        ('[tank]\nsize_m = [1, 1, 1]\n', r"a \[sensor\] table is needed"),
        ('[sensor]\npreset = "angels-9"\n', "angels-9"),
        ('[sensor]\npreset = "angels-4"\nfile = "x.json"\n', "exactly one of preset"),
        ('[sensor]\npreset = "angels-4"\n[[objects]]\nshape = "cone"\ncentre_m = [0, 0, 0]\n', "number 1 has shape 'cone'"),
        ('[sensor]\npreset = "angels-4"\n[[objects]]\nshape = "sphere"\nradius_m = 0.1\n', "needs centre_m"),
        ('[sensor]\npreset = "angels-4"\n[[objects]]\nshape = "sphere"\ncentre_m = [0, 0, 0]\nsize_m = [1, 1, 1]\n',
         "unknown key.*size_m"),
        ('[sensor]\npreset = "angels-4"\n[[objects]]\nshape = "box"\ncentre_m = [0, 0, 0]\nmaterial = "wood"\n', "wood"),
        ('[tank]\nsize_m = [1, 1, 1]\nwater_depth_m = 2\n[sensor]\npreset = "angels-4"\n', "water depth"),
        ('[sensor\n', "not valid TOML"),
        ('[sensors]\npreset = "angels-4"\n', "unknown key.*sensors"),
        ('[sensor]\npreset = "angels-4"\n[[objects]]\nshape = "sphere"\ncentre_m = [0, 0, 0]\nradius_m = -0.02\n',
         r"number 1: object sphere: radius_m must be positive"),
        ('[sensor]\npreset = "angels-4"\n[[objects]]\nshape = "box"\ncentre_m = [0, 0, 0]\nsize_m = [0.1, 0, 0.1]\n',
         "size_m must be positive"),
    ],
)
def test_bad_scene_files_are_refused_naming_file_and_entry(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as info:
        load_scene(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize("value", ['"salty"', "-0.05", "0", "nan", "true"])
def test_a_water_conductivity_that_is_not_one_is_refused_naming_the_file(tmp_path, value):
    from electrosense.meshes.scene_file import load_scene_settings

    path = tmp_path / "water.toml"
    path.write_text(f'[sensor]\npreset = "angels-4"\n[water]\nsigma_S_per_m = {value}\n')
    with pytest.raises(ValueError, match=r"\[water\] sigma_S_per_m must be a positive conductivity") as info:
        load_scene_settings(path)
    assert str(path) in str(info.value)


def test_overrides_replace_what_the_file_says():
    scene = load_scene(EXAMPLE)
    over = apply_overrides(scene, sensor="angels-2", pose="0.1,0.2,-0.1,0.5", tank=Tank((2.0, 2.0, 1.0)))
    assert over.sensor.name == "angels-2" and over.pose == Pose(0.1, 0.2, -0.1, 0.5)
    assert over.tank.size_m == (2.0, 2.0, 1.0) and over.objects == scene.objects
    assert apply_overrides(scene, unbounded=True).tank is None
    assert apply_overrides(None, sensor="angels-4").pose == Pose()
    with pytest.raises(ValueError, match="no sensor"):
        apply_overrides(None)
