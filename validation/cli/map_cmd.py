"""``esense map build``: the BEM over every pose a robot can reach at one depth, as one file (a tank map)."""
from __future__ import annotations

import click

from electrosense.validation.cli._parsing import finite_float, parse_tank, sensor_option


@click.group("map")
def map_group():
    """Tank maps: the BEM's K over the tank at one depth, interpolated, with its estimated error.

    Example: ``esense map build --sensor angels-4 --tank 1,1,1 --depth 0.8 --z 0 -o tank.map.npz``
    """


@map_group.command("build")
@click.option("--sensor", "sensor_spec", required=True, help="Sensor preset or sensor file.")
@click.option("--tank", "tank_text", required=True, help="Box tank LX,LY,LZ (m).")
@click.option("--depth", "depth_m", type=finite_float(positive=True), default=None,
              help="Water depth (m); default: the tank full.")
@click.option("--z", "z_m", type=finite_float(), default=0.0, show_default=True,
              help="Height of the sensor's centre (m, tank frame: 0 is mid-water).")
@click.option("--sigma", type=finite_float(positive=True), default=None,
              help="The water's conductivity (S/m), recorded as the map's default (K is kept at 1 S/m: it scales).")
@click.option("--wall-gap", "wall_gap_m", type=finite_float(positive=True), default=0.005, show_default=True,
              help="Closest the sensor's surface comes to a wall, floor or surface (m).")
@click.option("--spacing", "spacing_m", type=finite_float(positive=True), default=0.01, show_default=True,
              help="Grid of candidate positions (m).")
@click.option("--headings", "n_headings", type=int, default=48, show_default=True, help="Candidate headings per turn.")
@click.option("--target", type=finite_float(positive=True), default=1.7e-4, show_default=True,
              help="Largest estimated relative error of a receiver current at which the build stops.")
@click.option("--max-minutes", type=finite_float(positive=True), default=5.0, show_default=True,
              help="Wall-clock budget of the BEM; the map is saved as it stands, with its estimated error.")
@click.option("--edge-length", "edge_length_m", type=finite_float(positive=True), default=None,
              help="Sensor mesh edge (m); default: the diagnosis anchors' (3x the mesher's, edge-corrected).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="The map file (.npz); an existing map of the same scene is resumed.")
def build(sensor_spec, tank_text, depth_m, z_m, sigma, wall_gap_m, spacing_m, n_headings, target, max_minutes,
          edge_length_m, output):
    """Build (or resume) a tank map: the BEM at the poses of largest estimated error until ``--target``."""
    from electrosense.meshes.tank import Tank
    from electrosense.validation.simulation.tank_map import build_tank_map

    sensor = sensor_option(sensor_spec)
    tank = parse_tank(tank_text)
    if depth_m is not None:
        if depth_m > tank.size_m[2]:
            raise click.BadParameter(f"{depth_m} m of water does not fit a {tank.size_m[2]} m deep tank",
                                     param_hint="--depth")
        tank = Tank(tank.size_m, depth_m)
    options = {} if edge_length_m is None else {"edge_length_m": edge_length_m}
    m = build_tank_map(sensor, tank, z_m, path=output, target=target, wall_gap_m=wall_gap_m, spacing_m=spacing_m,
                       n_headings=n_headings, max_seconds=60.0 * max_minutes, bem_options=options,
                       sigma_S_per_m=sigma, progress=click.echo)
    last = m.history[-1]
    click.echo(f"{output}: {len(m.nodes)} BEM poses, estimated error max {100 * last['max_error']:.4f} %, RMS "
               f"{100 * last['rms_error']:.4f} % over the reachable poses ({last['seconds']:.0f} s)")
