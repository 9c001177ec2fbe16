"""``esense bench-sim``: the virtual bench, on a pseudo-terminal, a socket, or straight into a file."""
from __future__ import annotations

from pathlib import Path

import click

from electrosense.validation.cli._parsing import finite_float, parse_tank
from electrosense.validation.defaults import NOMINAL_SIGMA_S_PER_M


@click.command("bench-sim")
@click.option("--pty", "use_pty", is_flag=True, help="Serve on a pseudo-terminal (the default); its path is printed.")
@click.option("--port", default=None, metavar="socket://HOST:PORT",
              help="Serve on a TCP socket on this host and port instead (loopback; port 0: any free port).")
@click.option("-o", "--output", default=None, type=click.Path(dir_okay=False),
              help="No serial line: write the run straight into this bench log.")
@click.option("--overwrite", is_flag=True, help="With -o: replace an existing file.")
@click.option("--link", default=None, type=click.Path(dir_okay=False),
              help="Path of the stable link to the pseudo-terminal (default: a new temporary folder).")
@click.option("--sensor", default="angels-4", show_default=True, help="Sensor preset or sensor file.")
@click.option("--emitter", type=int, default=None, help="Emitting electrode (default: the last).")
@click.option("--model", type=click.Choice(["bem", "psm"]), default="bem", show_default=True,
              help="Model that gives the currents.")
@click.option("--psm-model", default=None, type=click.Path(exists=True, dir_okay=False),
              help="PSM JSON file (default: the PSM calibrated on the sensor's free-space BEM).")
@click.option("--tank", default="1,1,1", show_default=True, help="Inner tank size LX,LY,LZ in m, or none.")
@click.option("--depth", type=finite_float(positive=True), default=None, help="Water depth in m (default: the tank's height).")
@click.option("--sigma", type=finite_float(positive=True), default=NOMINAL_SIGMA_S_PER_M, show_default=True,
              help="Nominal water conductivity in S/m.")
@click.option("--tank-grading", type=finite_float(positive=True), default=None,
              help="BEM physics: the tank mesh's growth of edge per metre away from the sensor (default: the "
                   "BEM's, 0.25); 0.15 brings K about 3x closer to the converged BEM in a box, for about twice the "
                   "tank's triangles.")
@click.option("--wall-images", is_flag=True,
              help="BEM physics: each pose on its own tank mesh, the tank's flat faces within 8 cm of the sensor "
                   "image planes (exact walls: one meshed tank for the path is 0.03-0.06 % off within 15 mm of a "
                   "wall); a tank mesh per pose.")
@click.option("--edge-length", "edge_length_m", type=finite_float(positive=True), default=None,
              help="BEM physics: the sensor mesh's edge in m (default the BEM's for the sensor).")
@click.option("--path", "path_spec", default="wall-to-wall", show_default=True,
              help="Trajectory: wall-to-wall[:N], line:X0,Y0,Z0,YAW0:X1,Y1,Z1,YAW1:N, grid:X0,X1,NX:Y0,Y1,NY[:Z[:YAW]].")
@click.option("--passes", type=click.IntRange(min=1), default=1, show_default=True,
              help="Repeat the path, back and forth (numbered in the pass column).")
@click.option("--rate", type=finite_float(positive=True), default=10.0, show_default=True,
              help="Records per second.")
@click.option("--voltage", type=finite_float(positive=True), default=1.0, show_default=True, help="Emitter voltage U in V.")
@click.option("--temperature", type=finite_float(), default=20.0, show_default=True, help="Water temperature at start, C.")
@click.option("--effect", "effects", multiple=True, metavar="NAME=VALUE",
              help="Physical effect, repeatable: conductivity=-2% (true/nominal - 1), temperature_drift=0.5 (K over "
                   "the run, 2 %/K), contact_impedance=0.01 (ohm m^2), channel_gain=1.01,0.99,1 (per receiver), "
                   "pose_offset=DX,DY,DZ,DYAW (m, rad), water_depth=0.8 (m), tank_size=LX,LY,LZ (m), "
                   "unmodelled_object=sphere,X,Y,Z,R[,conducting|insulating|S/m] or cylinder,X,Y,R,H[,...].")
@click.option("--faults", default=None, metavar="KIND=N,...",
              help="Fault injection: corrupt, drop, garbage, disconnect, restart with counts, or all, or none.")
@click.option("--disconnect-s", type=finite_float(positive=True), default=1.0, show_default=True, help="How long a disconnection lasts.")
@click.option("--seed", type=int, default=None, help="Random seed (noise, faults).")
@click.option("--truth", default=None, type=click.Path(dir_okay=False),
              help="Also write what happened to every sample (true pose, fate) into this bench log.")
@click.option("--autostart", is_flag=True,
              help="Stream at once instead of waiting for the host's START (in the truth file, records written "
                   "before the host said anything are 'unheard': opening a port may flush them).")
@click.option("--exit-when-done", is_flag=True, help="Close the line when the run is over (default: wait for Ctrl-C).")
def bench_sim(use_pty, port, output, overwrite, link, sensor, emitter, model, psm_model, tank, depth, sigma,
              tank_grading, wall_images, edge_length_m, path_spec, passes, rate, voltage, temperature, effects, faults, disconnect_s, seed, truth, autostart,
              exit_when_done):
    """A virtual bench for tests and demos (SIMULATED data, labelled so).

    It streams records along a trajectory, in the bench's serial protocol,
    with the bench's noise (0.05 % on currents, 0.1 mm on positions), from
    the chosen model with optional physical effects and faults.

    Example: esense bench-sim --pty --sensor angels-4 --faults all, then
    esense acquire --port <printed path> -o run.csv --meta <printed meta>
    """
    import sys
    import threading

    from electrosense.meshes.sensor import load_sensor
    from electrosense.meshes.tank import Tank
    from electrosense.validation.bench.log import write_bench_log
    from electrosense.validation.bench.logger.meta_option import parse_meta_option
    from electrosense.validation.bench.virtual import (
        SIMULATOR_LABEL,
        BenchDevice,
        Effects,
        FaultPlan,
        PtyTransport,
        SocketTransport,
        VirtualBench,
        parse_path,
        repeat_passes,
    )
    from electrosense.validation.simulation.tank_map import IMAGE_FACES_WITHIN_M

    def say(text):
        click.echo(text, err=True)

    modes = sum([bool(use_pty), port is not None, output is not None])
    if modes > 1:
        raise click.UsageError("choose one of --pty, --port and -o")
    try:
        sens = load_sensor(sensor)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--sensor") from None
    if emitter is not None and not 1 <= emitter <= sens.n_electrodes:
        raise click.BadParameter(f"{emitter} is not an electrode of {sens.name} (1..{sens.n_electrodes})",
                                 param_hint="--emitter")
    if emitter is not None:
        sens = sens.with_emitter(emitter)
    if model != "bem" and (wall_images or tank_grading is not None):
        raise click.UsageError("--wall-images and --tank-grading are the BEM physics' (--model bem)")
    if tank.strip().lower() == "none":
        if depth is not None:
            raise click.UsageError("--depth needs a tank; --tank none is unbounded water")
        if tank_grading is not None or wall_images:
            raise click.UsageError("--tank-grading and --wall-images need a tank; --tank none is unbounded water")
        tank_obj = None
    else:
        tank_obj = parse_tank(tank)
        if depth is not None:
            try:
                tank_obj = Tank(tank_obj.size_m, depth)
            except ValueError as exc:
                raise click.BadParameter(str(exc), param_hint="--depth") from None
    try:
        fx = Effects.parse(effects)
        plan = FaultPlan.parse(faults, disconnect_s)
        poses, pass_numbers = repeat_passes(parse_path(path_spec, tank_obj.size_m if tank_obj else None), passes)
    except ValueError as exc:
        raise click.ClickException(str(exc)) from None
    if output is not None and plan.total:
        raise click.UsageError("--faults need a serial line (--pty or --port), not -o")
    if output is not None and truth is not None:
        raise click.UsageError("--truth records the fate of every record sent on a serial line (--pty or --port); "
                               "with -o every sample is written as computed, so there is no separate truth: "
                               "drop --truth, or serve on --pty/--port and log with esense acquire")

    tank_meta = "none" if tank_obj is None else ",".join(f"{v:g}" for v in tank_obj.size_m)
    meta_text = f"sensor={sensor},emitter={sens.emitter},tank={tank_meta},sigma={sigma:g}"
    if tank_obj is not None and depth is not None:
        meta_text += f",depth={depth:g}"
    meta = parse_meta_option(meta_text)
    meta.update({"temperature_C": temperature, "voltage_V": voltage})
    if output is not None:   # what the log will call the sensor (a file in its folder), checked before any work
        from electrosense.validation.bench.log.writer import sensor_for_log

        try:
            if Path(output).exists() and not overwrite:
                raise FileExistsError(f"{output} exists; pass --overwrite to replace it")
            if not Path(output).parent.is_dir():
                raise ValueError(f"{output}: its folder {Path(output).parent} does not exist")
            meta["sensor"] = sensor_for_log(sens, output, sensor, overwrite, write=False)
        except (FileExistsError, ValueError) as exc:
            raise click.ClickException(str(exc)) from None

    say(f"bench-sim: computing {len(poses)} samples with the {model.upper()} ...")
    try:
        bench = VirtualBench(sens, tank_obj, sigma, model=model, psm_model=psm_model, effects=fx,
                             temperature_C=temperature, seed=seed, **({"progress": True} if model == "bem" else {}),
                             **({"tank_grading": tank_grading} if tank_grading is not None else {}),
                             **({"image_faces_within_m": IMAGE_FACES_WITHIN_M} if wall_images else {}),
                             **({"edge_length_m": edge_length_m} if edge_length_m is not None else {}))
        run = bench.run(poses, rate_hz=rate, passes=pass_numbers, U_V=voltage)
    except ValueError as exc:
        raise click.ClickException(str(exc)) from None

    if output is not None:
        import pandas as pd

        rows = [run.record_values(i) for i in range(len(run))]
        frame = pd.DataFrame(rows, columns=list(run.columns))
        meta["source"] = f"{bench.describe()}; path {path_spec} x {passes} pass(es) at {rate:g} Hz"
        try:
            meta["sensor"] = sensor_for_log(sens, output, sensor, overwrite)
            write_bench_log(output, meta, frame, overwrite=overwrite)
        except (FileExistsError, ValueError) as exc:
            raise click.ClickException(str(exc)) from None
        say(f"bench-sim: wrote {len(run)} SIMULATED records to {output}")
        return

    try:
        if port is not None:
            host_port = port.removeprefix("socket://")
            host, _, number = host_port.rpartition(":")
            transport = SocketTransport(host or "127.0.0.1", int(number))
        else:
            transport = PtyTransport(link)
    except (ValueError, OSError) as exc:
        raise click.ClickException(f"cannot open the line: {exc}") from None
    device = BenchDevice(run, transport, rate_hz=rate, faults=plan, seed=seed,
                         name=f"esense bench-sim SIMULATOR (model {model})", autostart=autostart,
                         truth_path=truth, truth_meta=meta, say=say)
    click.echo(transport.path)
    sys.stdout.flush()
    say(f"bench-sim: {SIMULATOR_LABEL}")
    say(f"bench-sim: serving {len(run)} records at {rate:g} Hz on {transport.path}"
        + ("" if port is not None else f" (terminal {transport.device})"))
    say(f"bench-sim: faults: {plan.describe()}; effects: {fx.describe()}")
    say(f"bench-sim: log it with: esense acquire --port {transport.path} -o run.csv --meta {meta_text}")
    stop = threading.Event()
    try:
        report = device.serve(stop, linger_s=0.0 if exit_when_done else float("inf"))
    except KeyboardInterrupt:
        stop.set()
        report = device.report
    finally:
        transport.close()
    say(f"bench-sim: {report.text()}")
