"""``esense mesh``: labelled meshes of a sensor or a whole scene, with a picture.

Examples::

    esense mesh sensor angels-4 -o sensor.vtp --png sensor.png
    esense mesh sensor my_sensor.json -o sensor.ply --edge-length 0.003
    esense mesh scene --scene validation/data/example_scene.toml -o scene.vtp --png scene.png
    esense mesh scene --sensor angels-2 --tank 1,1,1 --depth 0.8 --pose 0.1,0,-0.1,0.5 -o scene.vtp

The mesh file's format follows its suffix: ``.vtp`` (ParaView; cell arrays
``electrode`` and ``region``, region names in the field data), ``.ply``
(labels as face properties) or ``.stl`` (geometry only). The mesh quality
(edge lengths, minimum angle, aspect ratio, watertightness, orientation) is
printed, and a mesh a BEM could not use is refused.
"""
from __future__ import annotations

import click

from electrosense.validation.cli._parsing import check_edge_length, finite_float, scene_from_options, scene_options

_MESH_SUFFIXES = (".vtp", ".vtk", ".ply", ".stl")


def _check_output(path: str) -> str:
    from pathlib import Path

    if Path(path).suffix.lower() not in _MESH_SUFFIXES:
        raise click.BadParameter(f"{path!r}: the mesh file must end in {', '.join(_MESH_SUFFIXES)}", param_hint="-o")
    return path


def _finish(mesh, output, png, title, emitter, solver_limits: bool = False):
    """Check, write and picture a mesh; print its quality (``solver_limits``: refuse only what the BEM refuses,
    1 degree and aspect 60, as for sector meshes, whose split caps' gaps narrow to the tip)."""
    from electrosense.meshes.io import write_mesh
    from electrosense.meshes.quality import check_mesh

    try:
        quality = check_mesh(mesh, **({"min_angle_deg": 1.0, "max_aspect_ratio": 60.0} if solver_limits else {}))
    except ValueError as exc:
        raise click.ClickException(str(exc)) from None
    click.echo(str(quality))
    if output:
        write_mesh(mesh, output)
        click.echo(f"wrote {output}")
    if png:
        from electrosense.meshes.render import render_mesh

        render_mesh(mesh, png, title=title, emitter=emitter)
        click.echo(f"wrote {png}")
    if not output and not png:
        click.echo("(nothing written: give -o FILE and/or --png FILE)")


@click.group("mesh")
def mesh():
    """Labelled triangle meshes (0 insulator, k electrode k) of a sensor or a scene."""


@mesh.command("sensor")
@click.argument("sensor")
@click.option("-o", "--output", type=click.Path(dir_okay=False), default=None,
              help="Mesh file to write: .vtp (labels and region names), .ply (labels) or .stl (geometry only).")
@click.option("--png", type=click.Path(dir_okay=False), default=None, help="Write a picture of the mesh (PNG).")
@click.option("--edge-length", "edge_length_m", type=finite_float(positive=True), default=None,
              help="Far-field edge length in metres (default: from the sensor's size); the mesh is graded finer "
                   "towards every electrode edge.")
@click.option("--emitter", type=int, default=None, help="Emitting electrode (default: the sensor's, the last one).")
def mesh_sensor_cmd(sensor, output, png, edge_length_m, emitter):
    """Mesh SENSOR (a preset such as angels-2, angels-4, or a sensor .json/.toml file) in the sensor frame."""
    from electrosense.meshes.sensor import load_sensor
    from electrosense.meshes.sensor_mesh import mesh_sensor

    if output:
        _check_output(output)
    try:
        description = load_sensor(sensor)
        if emitter is not None:
            description = description.with_emitter(emitter)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="SENSOR") from None
    check_edge_length(description, edge_length_m)
    m = mesh_sensor(description, edge_length_m=edge_length_m)
    _finish(m, output, png, f"{description.name}: {m.n_triangles} triangles", description.emitter,
            solver_limits=description.has_sectors)


@mesh.command("scene")
@scene_options(sigma=False)
@click.option("-o", "--output", type=click.Path(dir_okay=False), default=None,
              help="Mesh file of the whole scene in the tank frame: .vtp, .ply or .stl.")
@click.option("--png", type=click.Path(dir_okay=False), default=None, help="Write a picture of the scene (PNG).")
@click.option("--tank-edge-length", "tank_edge_length_m", type=finite_float(positive=True), default=None,
              help="Tank edge length nearest the sensor in metres (default: a twentieth of the sensor length); "
                   "it grows away from the sensor.")
@click.option("--tank-grading", type=finite_float(), default=0.25, show_default=True,
              help="Growth of the tank's edge length per metre of distance from the sensor.")
def mesh_scene_cmd(output, png, tank_edge_length_m, tank_grading, **scene_opts):
    """Mesh a scene: the sensor at its pose, the tank (graded towards the sensor) and the objects."""
    from electrosense.meshes.scene_mesh import mesh_scene

    if output:
        _check_output(output)
    scene, _, _ = scene_from_options(**scene_opts)
    edge_length_m = scene_opts["edge_length_m"]
    try:
        sm = mesh_scene(scene, edge_length_m, tank_edge_length_m=tank_edge_length_m, tank_grading=tank_grading)
    except ValueError as exc:  # a refused scene names its parts
        raise click.ClickException(str(exc)) from None
    _finish(sm.combined(), output, png, scene_title(scene), None if scene.sensor is None else scene.sensor.emitter)


def scene_title(scene) -> str:
    """One line naming a scene's sensor and pose, its tank and its own electrodes (a picture's title).

    >>> from electrosense.meshes import Scene
    >>> from electrosense.meshes.cylinder_tank import CylinderTank
    >>> from electrosense.meshes.objects import Sphere
    >>> from electrosense.meshes.surface_electrodes import BodyElectrode
    >>> scene_title(Scene(None, tank=CylinderTank(0.15, 0.3), electrodes=[BodyElectrode(Sphere((0, 0, 0)))]))
    'no sensor, in a cylindrical tank (radius 0.15 m, water 0.3 m deep), 1 electrode of its own'
    """
    parts = ["no sensor"]
    if scene.sensor is not None:
        p = scene.pose
        parts = [f"{scene.sensor.name} at ({p.x_m:g}, {p.y_m:g}, {p.z_m:g}) m, yaw {p.yaw_rad:g} rad"]
    tank = scene.tank
    if hasattr(tank, "size_m"):
        parts.append(f"in a {'x'.join(f'{v:g}' for v in tank.size_m)} m tank")
    elif tank is not None:
        parts.append(f"in a cylindrical tank (radius {tank.radius_m:g} m, water {tank.water_depth_m:g} m deep)")
    if scene.electrodes:
        n = len(scene.electrodes)
        parts.append(f"{n} electrode{'s' if n > 1 else ''} of its own")
    return ", ".join(parts)
