"""``esense conductance``: the BEM conductance matrix of a sensor, alone in water or in a tank.

Examples::

    esense conductance --sensor angels-4 --unbounded --json angels4.json
    esense conductance --sensor angels-2 --tank 1,1,1 --pose 0.3,0,0,0 --sigma 0.05
    esense conductance --mesh my_sensor.vtp --sigma 1 --contact-impedance 0.001
    esense conductance --scene bench.toml --vtp surface.vtp

The table printed is K (siemens): K[i, j] is the current leaving electrode i
into the water when electrode j is at 1 V and the others at 0 V, the sensor
isolated; S is K without the emitter's row and column (the paper's matrix),
and R_k = U / I_k the bench resistance of each receiver.
"""
from __future__ import annotations

import click

from validation.defaults import NOMINAL_SIGMA_S_PER_M

from ._parsing import check_edge_length, finite_float, parse_tank


def _table(g) -> str:
    import numpy as np

    n = g.n
    head = "        " + "".join(f"{'j=' + str(j):>14s}" for j in range(1, n + 1))
    rows = [head] + [f"  i={i:<4d}" + "".join(f"{g.K_S[i - 1, j - 1]:14.6e}" for j in range(1, n + 1))
                     for i in range(1, n + 1)]
    R = np.atleast_1d(g.resistance_ohm)
    rec = "  ".join(f"R{k} = {r:.4g} ohm" for k, r in zip(g.receivers, R))
    return "\n".join(["K (S), electrodes 1..n from the head, emitter %d:" % g.emitter] + rows + [rec])


@click.command("conductance")
@click.option("--sensor", "sensor_spec", default=None, help="Sensor preset (angels-2, angels-4) or sensor file (.json/.toml).")
@click.option("--mesh", "mesh_file", default=None, type=click.Path(exists=True, dir_okay=False),
              help="A closed labelled sensor mesh (.vtp/.ply with integer cell array 'electrode') instead of --sensor; "
                   "solved in unbounded water.")
@click.option("--scene", "scene_file", default=None, type=click.Path(exists=True, dir_okay=False),
              help="Scene file (TOML); the other flags override it.")
@click.option("--tank", "tank_text", default=None, help="Tank inner size LX,LY,LZ in metres (water fills it).")
@click.option("--unbounded", is_flag=True, help="Unbounded water (no tank), the default without --tank or --scene.")
@click.option("--pose", "pose_text", default=None, help="Sensor pose X,Y,Z,YAW (m, m, m, rad) in the tank frame.")
@click.option("--sigma", "sigma", type=finite_float(positive=True), default=None, help=f"Water conductivity in S/m (default: the scene file's, else {NOMINAL_SIGMA_S_PER_M}).")
@click.option("--contact-impedance", "z_c", type=float, default=None, help="Electrode contact impedance in ohm m^2.")
@click.option("--edge-length", "edge_length", type=float, default=None,
              help="Sensor mesh edge length far from electrode edges, in metres "
                   "(default: 0.6 x radius, at most length/30).")
@click.option("--no-edge-correction", "no_edge_correction", is_flag=True,
              help="K of the surface solution itself, without the electrode-edge correction "
                   "(bem/edge_correction.py; about 0.5 % lower at the default mesh).")
@click.option("--emitter", type=int, default=None, help="Emitting electrode number (default: the sensor's, the last).")
@click.option("--json", "json_out", default=None, type=click.Path(dir_okay=False),
              help="Write the result (K_S, S_S, sigma_S_per_m, emitter, triangles, seconds...) to this JSON file.")
@click.option("--vtp", "vtp_out", default=None, type=click.Path(dir_okay=False),
              help="Write the surface solution for the emitter at 1 V (cell data: potential_V, "
                   "current_density_A_per_m2) to this .vtp file.")
def conductance(sensor_spec, mesh_file, scene_file, tank_text, unbounded, pose_text, sigma, z_c, edge_length,
                no_edge_correction, emitter, json_out, vtp_out):
    """Conductance matrix K (and the paper's S) of a sensor by the BEM."""
    import json
    from dataclasses import replace

    from bem.solve import solve_scene

    if mesh_file and (sensor_spec or scene_file):
        raise click.UsageError("--mesh replaces --sensor and --scene; give one of them")
    if unbounded and tank_text:
        raise click.UsageError("--unbounded and --tank contradict each other")
    if edge_length is not None and not edge_length > 0:
        raise click.BadParameter(f"must be positive, got {edge_length}", param_hint="--edge-length")
    settings = {}
    try:
        if mesh_file:
            from meshes.io import read_mesh

            target = read_mesh(mesh_file)
            from meshes.quality import overlapping_shells

            overlaps = overlapping_shells(target)
            if overlaps:
                a, b, n = overlaps[0]
                raise click.BadParameter(
                    f"{mesh_file}: its closed surfaces intersect or lie inside one another ({n} vertices of surface "
                    f"{b + 1} are inside surface {a + 1}; {len(overlaps)} such pair(s)): solids must have water "
                    "between them, else the BEM solves another problem; fix the mesh",
                    param_hint="--mesh")
            if tank_text or pose_text:
                raise click.UsageError("--mesh is solved in unbounded water; --tank and --pose do not apply")
        else:
            from meshes.pose import Pose
            from meshes.scene import Scene
            from meshes.sensor import load_sensor

            scene = None
            if scene_file:
                from meshes.scene_file import load_scene, load_scene_settings

                scene = load_scene(scene_file)
                settings = load_scene_settings(scene_file)
            if scene is None:
                if not sensor_spec:
                    raise click.UsageError("give --sensor, --mesh or --scene")
                scene = Scene(load_sensor(sensor_spec))
            elif sensor_spec:
                scene = replace(scene, sensor=load_sensor(sensor_spec))
            if pose_text:
                scene = replace(scene, pose=Pose.parse(pose_text))
            if tank_text:
                scene = replace(scene, tank=parse_tank(tank_text))
            if unbounded:
                scene = replace(scene, tank=None)
            if pose_text and scene.tank is None:
                raise click.UsageError("--pose places the sensor in a tank, but the water is unbounded here (no "
                                       "--tank, no tank in the scene): every pose gives the same K; add --tank "
                                       "LX,LY,LZ")
            if emitter is not None:
                scene = replace(scene, sensor=scene.sensor.with_emitter(emitter))
            check_edge_length(scene.sensor, edge_length)
            target = scene
        if sigma is None:
            sigma = float(settings.get("water", {}).get("sigma_S_per_m", NOMINAL_SIGMA_S_PER_M))
        if z_c is None and "contact" in settings:
            z_c = settings["contact"].get("impedance_ohm_m2")
        solution = solve_scene(target, sigma, z_c, edge_length, edge_correction=not no_edge_correction)
    except click.ClickException:
        raise
    except (ValueError, MemoryError) as exc:
        raise click.ClickException(str(exc)) from None
    g = solution.conductance
    if mesh_file and emitter is not None:
        if not 1 <= emitter <= g.n:
            raise click.BadParameter(f"emitter {emitter} is not an electrode 1..{g.n}", param_hint="--emitter")
        g = type(g)(g.K_S, emitter, g.sigma_S_per_m, g.info)
    click.echo(_table(g))
    click.echo(f"S (S), receivers {list(g.receivers)}:\n{g.S_S}")
    click.echo(f"{g.info['triangles']} triangles, {g.info['seconds']:.2f} s, asymmetry {g.asymmetry:.1e}, "
               f"row-sum residue {g.row_sum_residue:.1e}, sigma {sigma} S/m"
               + ("" if solution.boundary.unbounded else ", in the tank")
               + (f", edge correction {100 * g.info['edge_correction_max_relative']:.2f} % of max |K|"
                  if "edge_correction_max_relative" in g.info else ", no edge correction"))
    if json_out:
        d = g.to_json_dict()
        d.update(model="bem", triangles=int(g.info["triangles"]), seconds=float(g.info["seconds"]),
                 unbounded=bool(solution.boundary.unbounded),
                 contact_impedance_ohm_m2=solution.z_c.tolist(),
                 edge_correction=solution.K_correction_S is not None,
                 K_surface_S=solution.K_surface_S.tolist(),
                 resistance_ohm=[float(r) for r in g.resistance_ohm])
        if not mesh_file:
            d.update(sensor=target.sensor.to_dict(), pose=target.pose.as_array().tolist(),
                     tank_size_m=None if target.tank is None else list(target.tank.size_m))
        with open(json_out, "w") as fh:
            json.dump(d, fh, indent=2)
        click.echo(f"wrote {json_out}")
    if vtp_out:
        import numpy as np

        V = np.zeros(g.n)
        V[g.emitter - 1] = 1.0
        solution.to_pyvista(V).save(vtp_out)
        click.echo(f"wrote {vtp_out}")
