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

from electrosense.validation.cli._parsing import finite_float, scene_from_options, scene_options
from electrosense.validation.defaults import NOMINAL_SIGMA_S_PER_M


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
@scene_options()
@click.option("--mesh", "mesh_file", default=None, type=click.Path(exists=True, dir_okay=False),
              help="A closed labelled sensor mesh (.vtp/.ply with integer cell array 'electrode') instead of --sensor; "
                   "solved in unbounded water.")
@click.option("--contact-impedance", "z_c", type=finite_float(), default=None,
              help="Electrode contact impedance in ohm m^2.")
@click.option("--no-edge-correction", "no_edge_correction", is_flag=True,
              help="K of the surface solution itself, without the electrode-edge correction "
                   "(bem/edge_correction.py; about 0.5 % lower at the default mesh).")
@click.option("--emitter", type=int, default=None, help="Emitting electrode (default: the sensor's, the last).")
@click.option("--json", "json_out", default=None, type=click.Path(dir_okay=False),
              help="Write the result (K_S, S_S, sigma_S_per_m, emitter, triangles, seconds...) to this JSON file.")
@click.option("--vtp", "vtp_out", default=None, type=click.Path(dir_okay=False),
              help="Write the surface solution for the emitter at 1 V (cell data: potential_V, "
                   "current_density_A_per_m2) to this .vtp file.")
def conductance(mesh_file, z_c, no_edge_correction, emitter, json_out, vtp_out, **scene_opts):
    """Conductance matrix K (and the paper's S) of a sensor by the BEM."""
    import json
    from dataclasses import replace

    from electrosense.bem.solve import solve_scene

    edge_length = scene_opts["edge_length_m"]
    settings = {}
    try:
        if mesh_file:
            if scene_opts["sensor_spec"] or scene_opts["scene_file"]:
                raise click.UsageError("--mesh replaces --sensor and --scene; give one of them")
            if scene_opts["tank_text"] or scene_opts["pose_text"] or scene_opts["depth_m"] is not None:
                raise click.UsageError("--mesh is solved in unbounded water; --tank, --depth and --pose do not apply")
            from electrosense.meshes.io import read_mesh
            from electrosense.meshes.quality import overlapping_shells

            target = read_mesh(mesh_file)
            overlaps = overlapping_shells(target)
            if overlaps:
                a, b, n = overlaps[0]
                raise click.BadParameter(
                    f"{mesh_file}: its closed surfaces intersect or lie inside one another ({n} vertices of surface "
                    f"{b + 1} are inside surface {a + 1}; {len(overlaps)} such pair(s)): solids must have water "
                    "between them, else the BEM solves another problem; fix the mesh", param_hint="--mesh")
            sigma = scene_opts["sigma"] if scene_opts["sigma"] is not None else NOMINAL_SIGMA_S_PER_M
        else:
            scene, sigma, settings = scene_from_options(**scene_opts)
            if emitter is not None:
                scene = replace(scene, sensor=scene.sensor.with_emitter(emitter))
            target = scene
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
