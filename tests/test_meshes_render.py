"""Pictures are not blank and show the electrodes; the mesh and view commands work end to end."""
import numpy as np
import pytest
from click.testing import CliRunner

from electrosense.meshes import render
from electrosense.meshes.labelled_mesh import concatenate
from electrosense.meshes.object_mesh import mesh_object
from electrosense.meshes.objects import Box, Sphere
from electrosense.meshes.render import EMITTER_COLOUR, RenderUnavailable, can_render_3d, electrode_colour, render_mesh
from electrosense.meshes.tank import Tank
from electrosense.meshes.tank_mesh import mesh_tank

needs_3d = pytest.mark.skipif(not can_render_3d(), reason="no offscreen OpenGL (EGL or OSMesa) for VTK here")


def read_png(path):
    import pyvista as pv

    img = pv.read(str(path))
    rgb = np.asarray(img.point_data[img.point_data.keys()[0]])[:, :3].astype(int)
    return rgb, img.dimensions


def colour_pixels(rgb, hex_colour, tol=60):
    """How many pixels are close in hue to a colour (shading changes brightness, not much the hue)."""
    target = np.array([int(hex_colour[i:i + 2], 16) for i in (1, 3, 5)])
    rgb_n = rgb / np.maximum(rgb.sum(axis=1, keepdims=True), 1)
    t_n = target / target.sum()
    return int(np.sum((np.abs(rgb_n - t_n).sum(axis=1) < 0.08) & (rgb.sum(axis=1) > tol)))


def toy_sensor_scene():
    """A labelled 'sensor' (two electrodes on a sphere) in a tank, with an object."""
    body = mesh_object(Sphere((0, 0, 0), radius_m=0.05), 0.01, region_name="sensor")
    x = body.centroids_m[:, 0]
    body.electrode[:] = np.where(x > 0.02, 1, np.where(x < -0.02, 2, 0))
    obj = mesh_object(Box((0.15, 0.1, 0), size_m=(0.05, 0.05, 0.05)), region_name="object_1")
    return body, concatenate([body, mesh_tank(Tank((0.6, 0.5, 0.4)), 0.1), obj])


@needs_3d
@pytest.mark.parametrize("emitter", [1, 2])
def test_picture_is_not_blank_and_shows_each_electrode(tmp_path, emitter):
    """Each electrode is in sight, the emitter in its own colour, whichever end it is at."""
    body, _ = toy_sensor_scene()
    png = render_mesh(body, tmp_path / "body.png", title="toy", window_size=(800, 500), emitter=emitter)
    rgb, dims = read_png(png)
    assert dims[0] * dims[1] == 800 * 500
    not_background = np.any(rgb < 245, axis=1).sum()
    assert not_background > 0.05 * len(rgb)
    receiver = 3 - emitter
    assert colour_pixels(rgb, EMITTER_COLOUR) > 2000, "the emitter is not in sight"
    assert colour_pixels(rgb, electrode_colour(receiver, emitter)) > 200, f"electrode {receiver} not visible"
    assert electrode_colour(receiver, emitter) != EMITTER_COLOUR


def test_offscreen_backend_is_chosen_once_for_children_too():
    import os

    name = render.offscreen_backend()
    assert name in ("egl", "osmesa", None)
    assert render.offscreen_backend() == name
    assert os.environ["ESENSE_OFFSCREEN_BACKEND"] == (name or "none")
    if name is not None:
        assert os.environ["VTK_DEFAULT_OPENGL_WINDOW"] == render.OFFSCREEN_BACKENDS[name]
    assert render._probe("vtkNoSuchRenderWindow") is False  # VTK falls back silently: the probe sees it


def test_without_offscreen_opengl_pictures_are_refused_clearly(tmp_path, monkeypatch):
    from electrosense.meshes.io import write_mesh
    from electrosense.validation.cli import main

    monkeypatch.setattr(render, "_chosen", [None])
    body, _ = toy_sensor_scene()
    with pytest.raises(RenderUnavailable, match="neither EGL nor OSMesa"):
        render_mesh(body, tmp_path / "body.png")
    assert not (tmp_path / "body.png").exists()
    write_mesh(body, tmp_path / "b.vtp")
    out = CliRunner().invoke(main, ["view", str(tmp_path / "b.vtp"), "--png", str(tmp_path / "v.png")])
    assert out.exit_code != 0 and "libosmesa6" in out.output and "Traceback" not in out.output


@needs_3d
def test_scene_picture_has_two_panels(tmp_path):
    _, scene = toy_sensor_scene()
    rgb, dims = read_png(render_mesh(scene, tmp_path / "scene.png", window_size=(1000, 500)))
    img = rgb.reshape(dims[1], dims[0], 3)
    for half in (img[:, :500], img[:, 500:]):
        assert np.any(half < 245, axis=2).mean() > 0.03


@needs_3d
def test_mesh_sensor_and_view_commands(tmp_path):
    pytest.importorskip("electrosense.meshes.sensor_mesh")
    from electrosense.validation.cli import main

    runner = CliRunner()
    out = runner.invoke(main, ["mesh", "sensor", "angels-2", "-o", str(tmp_path / "s.vtp"),
                               "--png", str(tmp_path / "s.png"), "--edge-length", "0.006"])
    assert out.exit_code == 0, out.output
    assert "watertight    yes" in out.output and (tmp_path / "s.png").stat().st_size > 10_000
    from electrosense.meshes.io import read_mesh

    m = read_mesh(tmp_path / "s.vtp")
    assert m.electrodes == (1, 2) and m.region_names == ("sensor",)

    out = runner.invoke(main, ["view", str(tmp_path / "s.vtp"), "--png", str(tmp_path / "v.png")])
    assert out.exit_code == 0, out.output
    assert np.any(read_png(tmp_path / "v.png")[0] < 245, axis=1).mean() > 0.02


def test_mesh_scene_command_with_scene_file_and_overrides(tmp_path):
    pytest.importorskip("electrosense.meshes.sensor_mesh")
    from pathlib import Path

    from electrosense.validation.cli import main

    example = Path(__file__).resolve().parents[1] / "validation" / "data" / "example_scene.toml"
    runner = CliRunner()
    out = runner.invoke(main, ["mesh", "scene", "--scene", str(example), "--pose", "0.1,-0.1,-0.1,0.5",
                               "-o", str(tmp_path / "scene.ply")])
    assert out.exit_code == 0, out.output
    from electrosense.meshes.io import read_mesh

    m = read_mesh(tmp_path / "scene.ply")
    assert m.region_names[:2] == ("sensor", "wall_x-") and "object_2" in m.region_names
    # the sensor moved to the overriding pose
    centre = m.region_mesh("sensor").vertices_m.mean(axis=0)
    assert np.allclose(centre, [0.1, -0.1, -0.1], atol=3e-3)
    out = runner.invoke(main, ["mesh", "scene", "--sensor", "angels-4", "--tank", "1,1,0.5", "--depth", "0.3",
                               "--pose", "0,0,0.1,0", "-o", str(tmp_path / "x.vtp")])
    assert out.exit_code != 0 and "out of the water across the free_surface" in out.output
    out = runner.invoke(main, ["mesh", "scene", "-o", str(tmp_path / "x.vtp")])
    assert out.exit_code != 0 and "no sensor" in out.output


@needs_3d
def test_view_refuses_clearly(tmp_path, monkeypatch):
    from electrosense.validation.cli import main, view_cmd

    body, _ = toy_sensor_scene()
    from electrosense.meshes.io import write_mesh

    write_mesh(body, tmp_path / "b.vtp")
    monkeypatch.setattr(view_cmd, "has_display", lambda: False)
    out = CliRunner().invoke(main, ["view", str(tmp_path / "b.vtp")])
    assert out.exit_code != 0 and "no display" in out.output and "--png" in out.output
    monkeypatch.setattr(view_cmd, "_html_available", lambda: False)
    out = CliRunner().invoke(main, ["view", str(tmp_path / "b.vtp"), "--html", str(tmp_path / "b.html")])
    assert out.exit_code != 0 and "trame" in out.output and "electrosense[html]" in out.output
    out = CliRunner().invoke(main, ["view", str(tmp_path / "b.vtp"), "--scalars", "nope", "--png", str(tmp_path / "n.png")])
    assert out.exit_code != 0 and "no data array 'nope'" in out.output
