"""Parsers of command-line values shared by several ``esense`` subcommands."""
from __future__ import annotations

import math

import click


class _FiniteFloat(click.ParamType):
    """A float that is finite (no inf, no nan), and positive when asked; errors name the option as typed."""

    name = "number"

    def __init__(self, positive: bool = False):
        self.positive = positive

    def convert(self, value, param, ctx):
        if isinstance(value, float) and math.isfinite(value) and (value > 0 or not self.positive):
            return value
        try:
            x = float(value)
        except (TypeError, ValueError):
            self.fail(f"{value!r} is not a number", param, ctx)
        if not math.isfinite(x):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        if self.positive and not x > 0:
            self.fail(f"{value!r}: must be positive", param, ctx)
        return x


def finite_float(positive: bool = False) -> click.ParamType:
    """A click type for a finite float (``positive``: > 0), refusing ``inf``, ``nan`` (and ``<= 0``).

    >>> finite_float(positive=True).convert("0.5", None, None)
    0.5
    """
    return _FiniteFloat(positive)


def parse_tank(text: str, param_hint: str = "--tank"):
    """``"LX,LY,LZ"`` (m) as a :class:`electrosense.meshes.tank.Tank`, or a click error naming the option."""
    from electrosense.meshes.tank import Tank

    try:
        size = [float(v) for v in text.split(",")]
    except ValueError:
        raise click.BadParameter(f"{text!r}: expected LX,LY,LZ in metres", param_hint=param_hint) from None
    if len(size) != 3:
        raise click.BadParameter(f"{text!r}: expected three lengths LX,LY,LZ (m)", param_hint=param_hint)
    try:
        return Tank(tuple(size))
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint=param_hint) from None


def check_edge_length(sensor, edge_length_m: float | None, param_hint: str = "--edge-length") -> None:
    """Refuse, before meshing, an edge length that is not positive or would make too many triangles.

    The count is estimated from the sensor's geometry (:func:`electrosense.meshes.sensor_mesh.estimate_triangles`).
    """
    if edge_length_m is None:
        return
    from electrosense.meshes.sensor_mesh import MAX_SENSOR_TRIANGLES, estimate_triangles

    if not (math.isfinite(edge_length_m) and edge_length_m > 0):
        raise click.BadParameter(f"must be a positive length in metres, got {edge_length_m}", param_hint=param_hint)
    try:
        n = estimate_triangles(sensor, edge_length_m)
    except ValueError as exc:
        raise click.BadParameter(str(exc).removeprefix("mesh_sensor: "), param_hint=param_hint) from None
    if n > MAX_SENSOR_TRIANGLES:
        raise click.BadParameter(
            f"{edge_length_m:g} m would mesh {sensor.name or 'the sensor'} with about {n:,} triangles (at most "
            f"{MAX_SENSOR_TRIANGLES:,}; a dense BEM needs 8 N^2 bytes): choose a larger edge length",
            param_hint=param_hint,
        )


# ------------------------------------------------------------------ shared scene options
SCENE_OPTION_NAMES = ("scene_file", "sensor_spec", "tank_text", "unbounded", "depth_m", "pose_text", "sigma",
                      "edge_length_m")


def scene_options(*, pose: bool = True, depth: bool = True, edge_length: bool = True, sigma: bool = True,
                  tank_default: str = "no tank (unbounded water)"):
    """Decorator: the options every simulating command shares, spelt and explained once.

    ``--scene``, ``--sensor``, ``--tank``, ``--unbounded``, ``--depth``,
    ``--pose``, ``--sigma``, ``--edge-length`` (``pose``, ``depth``,
    ``edge_length``, ``sigma`` False leave those out). Read them with
    :func:`scene_from_options`.
    """
    from electrosense.validation.defaults import NOMINAL_SIGMA_S_PER_M

    def decorate(command):
        opts = [
            click.option("--scene", "scene_file", type=click.Path(exists=True, dir_okay=False), default=None,
                         help="Scene file (TOML: sensor, tank, pose, objects, [water] sigma_S_per_m); the other "
                              "options override it."),
            click.option("--sensor", "sensor_spec", default=None,
                         help="Sensor preset (angels-2, angels-4) or sensor file (.json/.toml); default: the scene's."),
            click.option("--tank", "tank_text", default=None,
                         help=f"Tank inner size LX,LY,LZ in metres (default: the scene's, else {tank_default})."),
            click.option("--unbounded", is_flag=True, help="Unbounded water: no tank (drops the scene's tank)."),
        ]
        if depth:
            opts.append(click.option("--depth", "depth_m", type=finite_float(positive=True), default=None,
                                     help="Water depth in metres (default: the tank's height)."))
        if pose:
            opts.append(click.option("--pose", "pose_text", default=None,
                                     help="Sensor pose X,Y,Z,YAW (m, m, m, rad) in the tank frame (needs a tank)."))
        if sigma:
            opts.append(click.option("--sigma", "sigma", type=finite_float(positive=True), default=None,
                                     help=f"Water conductivity in S/m (default: the scene's [water], else "
                                          f"{NOMINAL_SIGMA_S_PER_M}, the paper's tank water)."))
        if edge_length:
            opts.append(click.option("--edge-length", "edge_length_m", type=finite_float(positive=True),
                                     default=None, help="BEM sensor mesh edge length far from the electrode edges, "
                                                        "in metres (default: the mesher's, from the sensor's size)."))
        for opt in reversed(opts):
            command = opt(command)
        return command

    return decorate


def sensor_option(spec: str, option: str = "--sensor"):
    """The sensor a ``--sensor`` value names (a preset or a sensor file), refused naming the option."""
    from electrosense.meshes.sensor import load_sensor

    try:
        return load_sensor(spec)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint=option) from None


def map_option(path, option: str = "--map"):
    """The tank map in ``path`` (:func:`electrosense.validation.simulation.tank_map.load_tank_map`), refused naming
    the option."""
    from electrosense.validation.simulation.tank_map import load_tank_map

    try:
        return load_tank_map(path)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint=option) from None


def scene_from_options(scene_file=None, sensor_spec=None, tank_text=None, unbounded=False, depth_m=None,
                       pose_text=None, sigma=None, edge_length_m=None, default_tank=None, default_sensor=None,
                       **_ignored):
    """The one reader of the shared scene options: ``(Scene, sigma_S_per_m, scene-file settings)``.

    The scene file first, the options over it; errors name the option as the user typed it.
    ``default_tank``: the tank when neither the options nor a scene give one and ``--unbounded`` is not set;
    ``default_sensor``: the sensor when neither give one (else that is refused).
    """
    from dataclasses import replace

    from electrosense.meshes.pose import Pose
    from electrosense.meshes.scene_file import SceneFileError, apply_overrides, load_scene, load_scene_settings
    from electrosense.meshes.tank import Tank
    from electrosense.validation.defaults import NOMINAL_SIGMA_S_PER_M

    if unbounded and tank_text:
        raise click.UsageError("--unbounded and --tank contradict each other: give one")
    if unbounded and depth_m is not None:
        raise click.UsageError("--depth needs a tank; --unbounded has none")
    scene, settings = None, {}
    if scene_file:
        try:
            scene, settings = load_scene(scene_file), load_scene_settings(scene_file)
        except (SceneFileError, ValueError) as exc:
            raise click.BadParameter(str(exc), param_hint="--scene") from None
    sensor = sensor_option(sensor_spec) if sensor_spec else None
    if scene is None and sensor is None:
        sensor = default_sensor
    if scene is None and sensor is None:
        raise click.UsageError("no sensor: give --sensor (a preset or a sensor file) or --scene")
    tank = parse_tank(tank_text) if tank_text else None
    if tank is None and scene is None and not unbounded and default_tank is not None:
        tank = default_tank
    pose = None
    if pose_text:
        try:
            pose = Pose.parse(pose_text)
        except ValueError as exc:
            raise click.BadParameter(str(exc), param_hint="--pose") from None
    scene = apply_overrides(scene, sensor=sensor, pose=pose, tank=tank, unbounded=unbounded)
    if depth_m is not None:
        if scene.tank is None:
            raise click.UsageError("--depth needs a tank: add --tank LX,LY,LZ")
        try:
            scene = replace(scene, tank=Tank(scene.tank.size_m, depth_m))
        except ValueError as exc:
            raise click.BadParameter(str(exc), param_hint="--depth") from None
    if pose_text and scene.tank is None:
        raise click.UsageError("--pose places the sensor in a tank, but the water is unbounded here (no --tank, no "
                               "tank in the scene), where every pose is the same problem; add --tank LX,LY,LZ")
    if edge_length_m is not None:
        check_edge_length(scene.sensor, edge_length_m)
    if sigma is None:
        sigma = float(settings.get("water", {}).get("sigma_S_per_m", NOMINAL_SIGMA_S_PER_M))
    return scene, float(sigma), settings
