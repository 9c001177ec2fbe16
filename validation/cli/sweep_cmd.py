"""``esense sweep``: a model (BEM or PSM) over a line or a grid of poses, locally or on a dask cluster.

Examples::

    esense sweep --model bem --sensor angels-4 --tank 1,1,1 --from -0.4,0 --to 0.4,0 --steps 161 -o wall2wall.csv
    esense sweep --model psm --sensor angels-4 --grid -0.4:0.4:81,-0.4:0.4:81 -o tank_map.zarr --plot tank_map.png
    esense sweep --model bem --sensor angels-2 --grid -0.4:0.4:41,-0.4:0.4:41,0:3.1416:4 \\
        --scheduler tcp://10.0.0.5:8786 -o map.zarr

Output by suffix: ``.csv`` a bench log (one row per pose, U_V = 1, the
receiver currents I<k>_A and resistances R<k>_ohm, ``source`` naming the
model); ``.zarr`` the chunked sweep store (resumable, xarray-readable);
``.nc`` the same as one netCDF file. Every run is resumable: ``.csv`` and
``.nc`` are computed through ``<output>.partial.zarr`` and written at the end.
"""
from __future__ import annotations

from pathlib import Path

import click

from electrosense.validation.bench.log.header import OBJECTS_META_KEY, describe_tank, objects_meta, tank_meta
from electrosense.validation.cli._parsing import SCENE_OPTION_NAMES, finite_float, scene_from_options, scene_options
from electrosense.validation.defaults import NOMINAL_TANK_M

_OUTPUT_SUFFIXES = (".csv", ".zarr", ".nc")
PSM_POSES_PER_EXTRA_WORKER = 200_000  # the PSM does ~10^4 poses/s per core; a worker process takes ~2 s to start


def _log_sensor(sensor, out: Path, o, write: bool = True) -> str:
    """The bench log's name for the sensor (:func:`~electrosense.validation.bench.log.writer.sensor_for_log`):
    the ``--sensor`` file, or the file the ``--scene`` names, where it lies in the log's folder."""
    from electrosense.meshes.scene_file import scene_sensor_file
    from electrosense.validation.bench.log.writer import sensor_for_log

    given = getattr(o, "sensor_spec", None)
    if not given and getattr(o, "scene_file", None):
        given = scene_sensor_file(o.scene_file)
    try:
        return sensor_for_log(sensor, out, given, o.overwrite, write)
    except FileExistsError as exc:
        raise click.ClickException(str(exc)) from None


def _open_store(store_path: Path, poses, sensor, identity: dict, chunk_poses: int, attrs: dict, ours: bool,
                overwrite: bool):
    """Resume the store of this very sweep, or start over where the folder holds another one.

    ``ours``: the store is the hidden ``.partial.zarr`` of a .csv/.nc output, so a different sweep in it
    (an earlier run with other arguments) is replaced, with a word. A ``.zarr`` output is the user's: a
    different sweep in it is replaced only with ``--overwrite``, else the message says how to go on.
    """
    from electrosense.validation.simulation.sweep.store import StoreError, SweepStore, remove_store

    def open_():
        return SweepStore.open_or_create(store_path, poses, sensor.n_electrodes, sensor.emitter, identity,
                                         chunk_poses, attrs)

    try:
        return open_()
    except StoreError as exc:
        if not store_path.exists():
            raise
        if not (ours or overwrite):
            raise StoreError(f"{exc}; or pass --overwrite to replace it with this sweep") from None
        click.echo(f"starting over: {store_path} {'held an earlier, different run' if ours else 'is replaced'} "
                   f"({str(exc).split('(', 1)[-1].split(')')[0]})")
        remove_store(store_path)
        return open_()


def _skipping_helps(model, sensor, tank, sigma, objects, psm_file, poses, tank_map=None) -> bool:
    """Whether ``--skip-blocked`` would run a sweep the model refused: it reaches some of ``poses`` and not all (a
    scene or a model that refuses every pose, e.g. an object out of the water or the PSM with a pole, it does not
    mend)."""
    from electrosense.validation.simulation.models import pose_evaluator, poses_reached

    try:
        probe = None if model == "bem" else pose_evaluator(model, sensor, tank, sigma, objects, psm_file,
                                                           **({"tank_map": tank_map} if model == "map" else {}))
        reached, _ = poses_reached(probe, sensor, tank, objects, poses)
    except ValueError:
        return False
    return bool(reached.any() and not reached.all())


def _bench_log_frame(C, poses, index=None):
    """The bench-log table of a sweep: t_s (the pose's ``index`` in the sweep, default 0, 1, ...), pose, U_V = 1,
    I<k>_A, R<k>_ohm."""
    import pandas as pd

    from electrosense.validation.bench.log.writer import bench_log_table

    I = C.receiver_currents_A(1.0)
    table = bench_log_table(poses, 1.0, I, C.receivers, t_s=None if index is None else [float(i) for i in index])
    table.update({f"R{k}_ohm": 1.0 / I[:, j] for j, k in enumerate(C.receivers)})
    return pd.DataFrame(table)


@click.command("sweep")
@click.option("--model", "model", type=click.Choice(["bem", "psm", "map"]), required=True,
              help="bem: the boundary-element reference; psm: the poly-spherical model; map: a tank map "
                   "(`esense map build`, given with --map; its sensor, tank and depth are the scene).")
@click.option("--map", "map_file", type=click.Path(exists=True, dir_okay=False),
              help="Tank map file (with --model map): its sensor, tank and objects; a --scene, --sensor or --tank "
                   "given beside it must be the same (the scene's sensor height is then the default --z).")
@click.option("--psm", "psm_file", type=click.Path(exists=True, dir_okay=False),
              help="PSM model file (from `esense calibrate`); default: calibrate on the sensor's free-space BEM (cached).")
@scene_options(pose=False, tank_default="1,1,1")
@click.option("--from", "from_xy", help="Line start X0,Y0 (m, tank frame).")
@click.option("--to", "to_xy", help="Line end X1,Y1 (m).")
@click.option("--steps", type=int, help="Number of poses on the line, both ends included.")
@click.option("--grid", "grid_text", help="Grid X0:X1:NX,Y0:Y1:NY[,YAW0:YAW1:NYAW] (m, m, rad; ends included).")
@click.option("--yaw", type=finite_float(), default=0.0, show_default=True, help="Heading in rad (line; grid without a yaw axis).")
@click.option("--z", "z_m", type=finite_float(), default=None,
              help="Height of the sensor centre in m (tank frame); default: the scene file's sensor height, the "
                   "map's depth, else 0.")
@click.option("--images", type=click.Choice(["complete", "paper8", "none"]), default="complete", show_default=True,
              help="PSM tank images.")
@click.option("--tank-edge-length", "tank_edge_length_m", type=finite_float(positive=True),
              help="BEM tank mesh edge length nearest the poses, in m (default: the BEM's).")
@click.option("--contact-impedance", "contact_impedance", type=finite_float(),
              help="Electrode contact impedance in ohm m^2.")
@click.option("--scheduler", help="dask scheduler address (tcp://host:port); default: Dask config, else this machine.")
@click.option("--workers", type=int,
              help="Local workers (1: in this process). Default: this machine's cores for the BEM; for the PSM, "
                   f"1 unless there are more than {PSM_POSES_PER_EXTRA_WORKER} poses (starting workers costs seconds).")
@click.option("--chunk", "chunk_poses", type=int, help="Poses per stored chunk (default: about 16 chunks per worker).")
@click.option("--plot", "plot_png", type=click.Path(dir_okay=False), help="Also write the tank map (grid sweeps) as PNG.")
@click.option("--plot-quantity", type=click.Choice(["resistance", "current_change"]), default="resistance",
              show_default=True, help="What the tank map shows.")
@click.option("--overwrite", is_flag=True,
              help="Replace an existing output: a .csv/.nc file, or a .zarr store of another sweep (a store of the "
                   "same sweep is resumed without it).")
@click.option("--skip-blocked", is_flag=True,
              help="Leave out the poses the model does not reach (the sensor beyond a wall or into an object, the "
                   "PSM's spheres across a wall, closer to a wall than a map reaches) instead of refusing the "
                   "sweep: NaN in the store, blank in the plot, no row in a bench log; their count said.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@click.option("-o", "--output", required=True, type=click.Path(),
              help="out.csv (bench log with R<k>_ohm columns), out.zarr (resumable store) or out.nc (netCDF).")
def sweep(**options):
    """Run a model over a line or a grid of poses and write the receiver currents and resistances.

    The sweep runs on this machine's cores, or on a dask cluster with
    --scheduler; results land chunk by chunk, and a killed sweep run again
    with the same arguments resumes where it stopped.

    Example: esense sweep --model psm --sensor angels-4 --from -0.4,0 --to 0.4,0 --steps 161 -o sweep.csv
    """
    from types import SimpleNamespace

    from electrosense.validation.cli._extras import require_extra
    from electrosense.validation.simulation.sweep.grid import GridError

    require_extra("sweep", "esense sweep")
    try:
        _sweep(SimpleNamespace(**options))
    except KeyboardInterrupt:
        out = Path(options["output"])
        store = out if out.suffix == ".zarr" else out.with_name(out.name + ".partial.zarr")
        kept = f"the poses computed so far are kept in {store}; " if store.exists() else ""
        click.echo(f"\nesense sweep: interrupted (Ctrl-C); {kept}run the same command again to resume", err=True)
        raise SystemExit(130) from None
    except click.ClickException:
        raise
    except (ValueError, GridError, FileExistsError) as exc:
        raise click.ClickException(str(exc)) from None
    except RuntimeError as exc:  # SchedulerError and the solvers' refusals
        raise click.ClickException(str(exc)) from None


def _scene_given(o, tank_only: bool = False) -> bool:
    """Whether the options say a scene (its tank, with ``tank_only``) beside the one a map carries."""
    tank = bool(o.scene_file or o.tank_text or getattr(o, "unbounded", False) or getattr(o, "depth_m", None) is not None)
    return tank or (not tank_only and bool(o.sensor_spec))


def _same_scene_as_map(o, tank_map):
    """``(Scene, its [water] sigma or None)`` of the scene options given beside ``--map``, refused where the
    sensor, the tank or the fixed objects differ from the map's (the map answers for its own scene only)."""
    from electrosense.validation.simulation.tank_map import same_scene

    scene, _, settings = scene_from_options(**{k: getattr(o, k) for k in SCENE_OPTION_NAMES if hasattr(o, k)},
                                            default_tank=tank_map.tank, default_sensor=tank_map.sensor)
    differs = []
    if scene.sensor.to_dict() != tank_map.sensor.to_dict():
        differs.append("the sensor given is not the map's")
    if _scene_given(o, tank_only=True) and not same_scene(scene.tank, tuple(scene.objects), tank_map.tank,
                                                          tank_map.objects):
        differs.append("the tank or the fixed objects given are not the map's")
    if differs:
        raise click.BadParameter(f"{'; '.join(differs)} ({o.map_file}): a map answers for its own scene; leave "
                                 "--scene/--sensor/--tank/--depth out to sweep the map's",
                                 param_hint="--map")
    return scene, settings.get("water", {}).get("sigma_S_per_m")


def _sweep(o):
    from electrosense.meshes.tank import Tank
    from electrosense.validation.simulation.models import code_version, pose_evaluator
    from electrosense.validation.simulation.sweep.grid import line_poses, parse_grid, parse_xy
    from electrosense.validation.simulation.sweep.runner import ctrl_c_held, default_chunk_poses, local_cores, run_sweep
    from electrosense.validation.simulation.sweep.store import export_netcdf, open_sweep, remove_store

    model, psm_file, workers, out = o.model, o.psm_file, o.workers, Path(o.output)
    images, edge_length_m, contact_impedance = o.images, o.edge_length_m, o.contact_impedance
    # ------------------------------------------------------------ what to run
    if out.suffix not in _OUTPUT_SUFFIXES:
        raise click.BadParameter(f"{out}: the output must end in {', '.join(_OUTPUT_SUFFIXES)}", param_hint="-o")
    if psm_file and model != "psm":
        raise click.BadParameter("--psm goes with --model psm", param_hint="--psm")
    if (model == "map") != bool(o.map_file):
        raise click.BadParameter("--model map and --map FILE go together", param_hint="--map")
    if model == "map":
        from electrosense.validation.cli._parsing import map_option
        from electrosense.validation.defaults import NOMINAL_SIGMA_S_PER_M

        tank_map = map_option(o.map_file)
        sensor, tank, objects = tank_map.sensor, tank_map.tank, tank_map.objects
        sigma = o.sigma or tank_map.sigma_S_per_m or NOMINAL_SIGMA_S_PER_M
        if _scene_given(o):   # the map's scene, said again: checked, never mixed
            given = _same_scene_as_map(o, tank_map)
            sigma = o.sigma or given[1] or sigma
            if o.z_m is None and o.scene_file:
                o.z_m = given[0].pose.z_m
        o.z_m = tank_map.z_range_m[0] if o.z_m is None else o.z_m
    else:
        scene, sigma, _ = scene_from_options(**{k: getattr(o, k) for k in SCENE_OPTION_NAMES if hasattr(o, k)},
                                             default_tank=Tank(NOMINAL_TANK_M))
        sensor, tank, objects = scene.sensor, scene.tank, tuple(scene.objects)
        if o.z_m is None and o.scene_file:
            o.z_m = scene.pose.z_m     # the scene's sensor height, as `esense map build --scene` takes it
    o.z_m = 0.0 if o.z_m is None else o.z_m

    grid = None
    if o.grid_text:
        if o.from_xy or o.to_xy or o.steps:
            raise click.BadParameter("give either --grid or --from/--to/--steps", param_hint="--grid")
        grid = parse_grid(o.grid_text, yaw_rad=o.yaw, z_m=o.z_m)
        poses = grid.poses
    else:
        if not (o.from_xy and o.to_xy and o.steps):
            raise click.BadParameter("give --from X0,Y0 --to X1,Y1 --steps N, or --grid", param_hint="--from")
        poses = line_poses(parse_xy(o.from_xy, "--from"), parse_xy(o.to_xy, "--to"), o.steps, o.yaw, o.z_m)
    if o.plot_png and grid is None:
        raise click.BadParameter("--plot draws a tank map: it needs --grid", param_hint="--plot")
    final = None if out.suffix == ".zarr" else out
    if final is not None and final.exists() and not o.overwrite:
        raise click.ClickException(f"{final} exists; pass --overwrite to replace it")
    store_path = out if final is None else out.with_name(out.name + ".partial.zarr")
    if final is not None and final.exists() and o.overwrite and store_path.exists():
        remove_store(store_path)  # --overwrite: the run starts over, not from an older partial run
    if final is not None and final.suffix == ".csv":   # the sensor file the log will name, checked before any work
        _log_sensor(sensor, final, o, write=False)

    bem_options = {} if edge_length_m is None else {"edge_length_m": edge_length_m}
    if o.tank_edge_length_m is not None:
        if model != "bem":
            raise click.BadParameter("--tank-edge-length is a BEM option", param_hint="--tank-edge-length")
        bem_options["tank_edge_length_m"] = o.tank_edge_length_m
    model_options = {"images": images} if model == "psm" else {"map": Path(o.map_file).name} if model == "map" else {}
    model_options.update(bem_options)
    if contact_impedance is not None:
        model_options["contact_impedance_ohm_m2"] = contact_impedance
    psm_description = None
    if psm_file:
        from electrosense.psm import PolySphericalModel

        psm_description = PolySphericalModel.load(psm_file).to_json_dict()
    identity = {
        "model": model,
        "sensor_name": sensor.name,
        "sensor": sensor.to_dict(),
        "water_depth_m": None,
        **tank_meta(tank),                      # a cylinder's radii beside its bounding box
        "objects": objects_meta(objects),
        "sigma_S_per_m": float(sigma),
        "model_options": model_options,
        "psm_model": psm_description,
        "code_version": code_version(),
    }
    attrs = {"command": "esense sweep", "grid": grid.to_dict() if grid is not None else "none (a line of poses)"}
    if grid is None:
        attrs.pop("grid")

    # -------------------------------------------------------------- the run
    if workers is None and model == "psm" and len(poses) <= PSM_POSES_PER_EXTRA_WORKER:
        workers = 1
    n_workers = workers or local_cores()
    # the model is set up (and may refuse) before any store exists, so a refusal leaves nothing behind
    try:
        evaluator = pose_evaluator(model, sensor, tank, sigma, objects, psm_file, contact_impedance, images,
                                   poses=poses, skip_blocked=o.skip_blocked, **bem_options,
                                   **({"tank_map": tank_map} if model == "map" else {}))
    except ValueError as exc:   # a pose the model does not reach (ModelError, PlacementError, the scene's check)
        helps = not o.skip_blocked and _skipping_helps(model, sensor, tank, sigma, objects, psm_file, poses,
                                                       tank_map if model == "map" else None)
        hint = " (--skip-blocked leaves out the poses the model does not reach)" if helps else ""
        raise click.ClickException(f"{exc}{hint}") from None
    n_blocked = getattr(evaluator, "n_blocked", 0)
    if n_blocked:
        click.echo(f"{n_blocked} of {len(poses)} poses left out (NaN), where the model does not reach: "
                   f"{evaluator.why}")
        attrs["blocked_poses"] = n_blocked
    chunk_poses = o.chunk_poses or default_chunk_poses(len(poses), n_workers)
    with ctrl_c_held() as release:   # a store is written whole; a Ctrl-C meanwhile is raised after it
        store = _open_store(store_path, poses, sensor, identity, chunk_poses, attrs, ours=final is not None,
                            overwrite=o.overwrite)
        release()
    pending = store.pending_chunks()
    if pending:
        n_left = sum(b - a for a, b in pending)
        if n_left < len(poses):
            click.echo(f"resuming {store_path}: {len(poses) - n_left} of {len(poses)} poses already computed")
        where = describe_tank(tank)
        click.echo(f"{model.upper()}: {sensor.name}, {where}, "
                   f"sigma {sigma:g} S/m, {n_left} poses to compute")
        result = run_sweep(evaluator, poses, store, scheduler=o.scheduler, workers=workers, progress=not o.quiet)
        C, reached = result.conductance, result.reached
        click.echo(f"computed {result.n_computed} poses in {result.seconds:.1f} s "
                   f"({result.poses_per_s:.3g} poses/s, {result.workers} worker{'s' if result.workers > 1 else ''})")
    else:
        click.echo(f"{store_path}: all {len(poses)} poses already computed")
        C, reached = store.conductance(sigma, reached_only=True), store.reached

    # ------------------------------------------------------------ the output
    if out.suffix == ".csv":
        from electrosense.validation.bench.log import write_bench_log

        source = f"esense sweep --model {model} ({dict(bem='BEM', psm='PSM', map='tank map of the BEM')[model]}; {code_version()})"
        meta = {
            "sensor": _log_sensor(sensor, out, o),
            "emitter": sensor.emitter,
            **tank_meta(tank),
            "sigma_S_per_m": float(sigma),
            "voltage_V": 1.0,
            "source": source,
            "notes": "simulated sweep: t_s is the pose index (one nominal second per pose); U_V = 1 V; "
                     "R<k>_ohm = U/I of receiver k",
            "model_options": model_options,
        }
        if objects:
            meta[OBJECTS_META_KEY] = objects_meta(objects)
        if not reached.all():
            meta["notes"] += (f"; {int((~reached).sum())} poses the model does not reach left out "
                              "(--skip-blocked): t_s keeps every pose's index")
        write_bench_log(out, meta, _bench_log_frame(C, poses[reached], reached.nonzero()[0]),
                        overwrite=o.overwrite)
    elif out.suffix == ".nc":
        export_netcdf(store_path, out)
    if o.plot_png:
        from electrosense.validation.simulation.sweep.plot import plot_tank_map

        plot_tank_map(open_sweep(store_path), o.plot_png, quantity=o.plot_quantity)
        click.echo(f"wrote {o.plot_png}")
    if final is not None:
        remove_store(store_path)
    click.echo(f"wrote {out}")

