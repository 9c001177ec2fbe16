"""``esense map build`` / ``esense map info``: the BEM over every pose a robot can reach, as one file (a tank map)."""
from __future__ import annotations

import math

import click

from electrosense.validation.cli._parsing import finite_float, sensor_option


@click.group("map")
def map_group():
    """Tank maps: the BEM's K over the tank at one depth (or a band), interpolated, with its estimated error.

    Example: ``esense map build --sensor angels-4 --tank 1,1,1 --depth 0.8 --z 0 -o tank.map.npz``
    """


def parse_map_tank(text: str, depth_m):
    """``LX,LY,LZ`` (a box) or ``cylinder:R,H`` (m), with the water ``depth_m`` (None: full)."""
    from electrosense.meshes.cylinder_tank import CylinderTank
    from electrosense.meshes.tank import Tank

    kind, _, numbers = text.rpartition(":")
    try:
        values = [float(v) for v in numbers.split(",")]
    except ValueError:
        raise click.BadParameter(f"{text!r}: expected LX,LY,LZ or cylinder:R,H in metres", param_hint="--tank") from None
    try:
        if kind == "cylinder" and len(values) == 2:
            return CylinderTank(values[0], values[1], depth_m)
        if kind == "" and len(values) == 3:
            return Tank(tuple(values), depth_m)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--tank" if depth_m is None else "--tank/--depth") from None
    raise click.BadParameter(f"{text!r}: expected LX,LY,LZ (a box) or cylinder:R,H (m)", param_hint="--tank")


def parse_depths(text: str):
    """``Z`` or ``Z0:Z1`` (a band), m in the tank frame."""
    try:
        z = [float(v) for v in text.split(":")]
    except ValueError:
        raise click.BadParameter(f"{text!r}: expected Z or Z0:Z1 (m)", param_hint="--z") from None
    if not all(map(math.isfinite, z)):
        raise click.BadParameter(f"{text!r}: a height must be a finite number (m)", param_hint="--z")
    if len(z) == 1:
        return z[0]
    if len(z) == 2 and z[0] < z[1]:
        return (z[0], z[1])
    raise click.BadParameter(f"{text!r}: expected Z or Z0:Z1 with Z0 < Z1 (m)", param_hint="--z")


@map_group.command("build")
@click.option("--scene", "scene_file", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Scene file (sensor, tank, fixed objects, [water]); the options below override it.")
@click.option("--sensor", "sensor_spec", default=None, help="Sensor preset or sensor file.")
@click.option("--tank", "tank_text", default=None, help="Box tank LX,LY,LZ, or cylinder:R,H (m).")
@click.option("--depth", "depth_m", type=finite_float(positive=True), default=None,
              help="Water depth (m); default: the tank full (or the scene's).")
@click.option("--z", "z_text", default=None,
              help="Height of the sensor's centre (m, tank frame: 0 is mid-height of the tank), or a band Z0:Z1; "
                   "default: the scene's sensor pose, else 0.")
@click.option("--sigma", type=finite_float(positive=True), default=None,
              help="The water's conductivity (S/m), recorded as the map's default (K is kept at 1 S/m: it scales).")
@click.option("--wall-gap", "wall_gap_m", type=finite_float(positive=True), default=0.005, show_default=True,
              help="Closest the sensor's surface comes to a wall, floor, surface or object (m).")
@click.option("--spacing", "spacing_m", type=finite_float(positive=True), default=0.01, show_default=True,
              help="Grid of candidate positions (m).")
@click.option("--headings", "n_headings", type=click.IntRange(4, 720), default=48, show_default=True,
              help="Candidate headings per turn.")
@click.option("--target", type=finite_float(positive=True), default=1.7e-4, show_default=True,
              help="Estimated relative error (RMS over the reachable poses) of a receiver current at which the build "
                   "stops (and --target-max at most).")
@click.option("--target-max", type=finite_float(positive=True), default=5e-4, show_default=True,
              help="Largest estimated relative error at which the build stops.")
@click.option("--max-minutes", type=finite_float(positive=True), default=4.5, show_default=True,
              help="Wall-clock budget; the map is saved as it stands, with its estimated error.")
@click.option("--max-cpu-minutes", type=finite_float(positive=True), default=None,
              help="CPU budget, every process counted (default: workers x --max-minutes): on a busy machine the "
                   "same command then builds the same map.")
@click.option("--workers", type=click.IntRange(1, 64), default=2, show_default=True,
              help="Processes solving the BEM.")
@click.option("--edge-length", "edge_length_m", type=finite_float(positive=True), default=None,
              help="Sensor mesh edge (m) of the reference BEM, the one the map reproduces; default: the mesher's.")
@click.option("--coarse-factor", type=click.FloatRange(min=1.0), default=3.0, show_default=True,
              help="Most BEM poses on a sensor mesh this much coarser (3.5x cheaper at 3; at most the sensor's "
                   "diameter, the mesher's coarsest), corrected by the reference mesh at fewer poses; 1: every pose "
                   "on the reference mesh.")
@click.option("--tank-edge-length", "tank_edge_length_m", type=finite_float(positive=True), default=None,
              help="Tank mesh edge near the sensor (m); default: the mesher's.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="The map file (.npz); an existing map of the same scene is resumed.")
def build(scene_file, sensor_spec, tank_text, depth_m, z_text, sigma, wall_gap_m, spacing_m, n_headings, target,
          target_max, max_minutes, max_cpu_minutes, workers, edge_length_m, coarse_factor, tank_edge_length_m, output):
    """Build (or resume) a tank map: the BEM at the poses of largest estimated error until the target."""
    from dataclasses import replace

    from electrosense.validation.simulation.tank_map import build_tank_map

    sensor, tank, objects, scene_z = None, None, (), None
    if scene_file:
        from electrosense.meshes.scene_file import SceneFileError, load_scene, load_scene_settings

        try:
            scene, settings = load_scene(scene_file), load_scene_settings(scene_file)
        except (SceneFileError, ValueError) as exc:
            raise click.BadParameter(str(exc), param_hint="--scene") from None
        sensor, tank, objects, scene_z = scene.sensor, scene.tank, tuple(scene.objects), scene.pose.z_m
        sigma = sigma or settings.get("water", {}).get("sigma_S_per_m")
    if sensor_spec:
        sensor = sensor_option(sensor_spec)
    if tank_text:
        tank = parse_map_tank(tank_text, depth_m)
    elif tank is not None and depth_m is not None:
        try:
            tank = replace(tank, water_depth_m=depth_m)
        except ValueError as exc:
            raise click.BadParameter(str(exc), param_hint="--depth") from None
    if sensor is None:
        raise click.UsageError("no sensor: give --sensor (a preset or a sensor file) or --scene")
    if tank is None:
        raise click.UsageError("a map is of a tank: give --tank LX,LY,LZ (or cylinder:R,H) or a --scene with one")
    if z_text is None and scene_z is not None:
        click.echo(f"z = {scene_z:g} m, the scene's sensor pose (--z to choose another)")
    z_m = parse_depths(z_text) if z_text is not None else float(scene_z or 0.0)
    options = {k: v for k, v in (("edge_length_m", edge_length_m), ("tank_edge_length_m", tank_edge_length_m))
               if v is not None}
    try:
        m = build_tank_map(sensor, tank, z_m, path=output, objects=objects, target=target, target_max=target_max,
                           wall_gap_m=wall_gap_m, spacing_m=spacing_m, n_headings=n_headings,
                           max_seconds=60.0 * max_minutes, bem_options=options, coarse_factor=coarse_factor,
                           sigma_S_per_m=sigma, workers=workers,
                           max_cpu_seconds=None if max_cpu_minutes is None else 60.0 * max_cpu_minutes,
                           progress=click.echo)
    except ValueError as exc:
        raise click.ClickException(str(exc)) from None
    last = m.history[-1]
    click.echo(f"{output}: {len(m.nodes)} BEM poses ({len(m.ref_index)} on the reference sensor mesh), estimated "
               f"error RMS {100 * last['rms_error']:.4f} %, max "
               f"{100 * last['max_error']:.4f} % over the reachable poses ({last['seconds']:.0f} s wall, "
               f"{last['cpu_seconds']:.0f} s CPU)")


@map_group.command("info")
@click.argument("map_file", type=click.Path(exists=True, dir_okay=False))
def info(map_file):
    """What a map holds: scene, sensor, depth, BEM poses, estimated error, code version."""
    from electrosense.validation.cli._parsing import map_option
    from electrosense.validation.simulation.tank_map import estimate_ratios

    m = map_option(map_file, "MAP_FILE")
    meta = m.meta()
    last = m.history[-1] if m.history else {}
    click.echo(f"sensor {m.sensor.name} ({m.sensor.n_electrodes} electrodes), tank {meta['tank']}, "
               f"{len(m.objects)} fixed object(s)")
    for i, o in enumerate(m.objects, start=1):
        material = "conducting" if o.is_conducting else "insulating" if o.is_insulating else \
            f"{o.conductivity_S_per_m:g} S/m"
        size = {k: v for k, v in vars(o).items() if k in ("radius_m", "height_m", "size_m", "yaw_rad")}
        click.echo(f"  object {i} ({o.label}): {material}, centre {tuple(round(c, 4) for c in o.centre_m)} m, "
                   + ", ".join(f"{k} {v}" for k, v in size.items()))
    click.echo(f"z = {meta['z_m']} m, closest {1e3 * m.wall_gap_m:g} mm to a wall; {len(m.nodes)} BEM poses "
               f"(sensor mesh {m.coarse_factor:.3g}x the reference's), {len(m.ref_index)} on the reference mesh; "
               + (f"sigma {m.sigma_S_per_m:g} S/m" if m.sigma_S_per_m is not None
                  else "no conductivity recorded (K kept at 1 S/m: a log's or --sigma scales it)"))
    if last:
        click.echo(f"estimated error RMS {100 * last['rms_error']:.4f} %, max {100 * last['max_error']:.4f} %; built in "
                   f"{last['seconds']:.0f} s wall, {last.get('cpu_seconds', float('nan')):.0f} s CPU")
    ratios = estimate_ratios(m.history)
    if ratios:
        names = {"coarse": "coarse interpolant", "ref": "correction"}
        click.echo("its estimate checked at each round's poses before they were solved, actual / estimated RMS "
                   "(the rounds go where the estimate is largest): "
                   + ", ".join(f"{names.get(f, f)} {r:.2f} ({n} round{'s' * (n != 1)})" for f, (n, r) in ratios.items()))
    click.echo(f"BEM options {meta['bem_options']}; {m.code}")
