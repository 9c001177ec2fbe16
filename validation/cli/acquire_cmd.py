"""``esense acquire``: log the bench's serial line into a bench log, losing nothing."""
from __future__ import annotations

import click

from electrosense.validation.cli._parsing import finite_float


@click.command("acquire")
@click.option("--port", required=True, metavar="PORT_OR_URL",
              help="Serial port or any pyserial URL: /dev/ttyUSB0, a pseudo-terminal path, socket://HOST:PORT, loop://.")
@click.option("--baud", default=115200, show_default=True, help="Baud rate (ignored by sockets and pseudo-terminals).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Bench log to write (CSV, format version 1); refused if it exists unless --append.")
@click.option("--meta", "meta_texts", multiple=True, required=True, metavar="KEY=VALUE,...",
              help="Meta of the log: sensor=angels-4,emitter=4,tank=1,1,1,sigma=0.0354 (tank=none for unbounded "
                   "water; also depth=, temperature=, voltage=, notes=, any key). Repeatable.")
@click.option("--samples", type=click.IntRange(min=1), default=None, help="Stop after this many records written.")
@click.option("--seconds", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Stop after this many seconds.")
@click.option("--append", is_flag=True, help="Go on writing an existing log of the same run.")
@click.option("--quiet", "-q", is_flag=True, help="No live status line (for scripts); the summary is still printed.")
@click.option("--fields", default=None, metavar="NAME,NAME,...",
              help="Field names of a record, for a device that does not answer ID (default: from its hello line).")
@click.option("--no-start", is_flag=True, help="Do not send START to the device (it streams by itself).")
@click.option("--voltage", type=finite_float(positive=True), default=None,
              help="Ask the device for this emitter voltage U in V (command VOLT) before starting it.")
@click.option("--reconnect-interval", default=0.5, show_default=True, type=click.FloatRange(min=0.01),
              help="Seconds between attempts to reopen a lost port.")
def acquire(port, baud, output, meta_texts, samples, seconds, append, quiet, fields, no_start, voltage,
            reconnect_interval):
    """Record the bench's serial line into a bench log.

    Every checked record is appended to OUTPUT as it arrives (flushed at each
    record, synced to disk within half a second). Corrupt, garbled, duplicate
    or refused lines go to OUTPUT.rejected with the reason, with the events
    (gaps in the sequence, device restarts, lost port). The port may vanish
    and come back: the logger waits and goes on in the same file. Ctrl-C
    stops cleanly with a summary.

    Example: esense acquire --port /dev/ttyACM0 -o run.csv
    --meta sensor=angels-4,emitter=4,tank=1,1,1,sigma=0.0354 --seconds 60
    """
    import signal
    from pathlib import Path

    from electrosense.validation.bench.logger import Logger, parse_meta_option

    meta = {}
    try:
        for text in meta_texts:
            meta.update(parse_meta_option(text))
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--meta") from None
    try:   # (a log that exists without --append is the logger's to refuse: no copy of a sensor beside it)
        if "sensor" in meta and (append or not Path(output).exists()):
            meta["sensor"] = _log_sensor_name(meta["sensor"], output)
    except (FileExistsError, ValueError) as exc:
        raise click.ClickException(str(exc)) from None

    try:
        logger = Logger(port, output, meta, baudrate=baud, samples=samples, seconds=seconds, append=append,
                        quiet=quiet, fields=fields.split(",") if fields else None,
                        reconnect_interval_s=reconnect_interval, start_device=not no_start,
                        voltage_V=voltage)
        # Ctrl-C and SIGTERM stop the loop at its next turn: the record in hand is finished, the file closed
        signal.signal(signal.SIGINT, lambda signum, frame: logger.request_stop("interrupt (Ctrl-C)"))
        signal.signal(signal.SIGTERM, lambda signum, frame: logger.request_stop("SIGTERM"))
        summary = logger.run()
    except (FileExistsError, ValueError, OSError) as exc:
        raise click.ClickException(str(exc)) from None
    click.echo(summary.text(), err=True)


def _log_sensor_name(spec, output):
    """What the log calls the ``--meta`` sensor: as given where the log can read it (a preset, a file in the
    log's folder), and a sensor file given by a path from here that the log's folder does not hold by its name
    (an absolute path, one from the working folder) as :func:`sensor_for_log` names it (relative to the log's
    folder where it lies there, else a copy beside the log): a path in a log never leads out of its folder."""
    from pathlib import Path

    from electrosense.meshes.sensor import PRESETS, load_sensor
    from electrosense.validation.bench.log.writer import sensor_for_log

    if not isinstance(spec, str) or spec in PRESETS or not Path(spec).is_file():
        return spec
    if not Path(spec).is_absolute() and (Path(output).parent / spec).is_file():
        return spec
    return sensor_for_log(load_sensor(spec), output, spec)
