"""``esense localise``: the robot's track from its currents alone, by a tank map and by the PSM, with their bounds."""
from __future__ import annotations

import click


@click.command("localise")
@click.argument("log", type=click.Path(exists=True, dir_okay=False))
@click.option("--map", "map_file", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Tank map of the log's sensor, tank and depth (esense map build).")
@click.option("--psm-model", type=click.Path(exists=True, dir_okay=False), default=None,
              help="PSM JSON for the comparison (default: the one calibrated on the sensor's free-space BEM).")
@click.option("-o", "--out", "outdir", required=True, type=click.Path(file_okay=False),
              help="Output folder: localise.json, localise.png, localise_tracks.npz.")
@click.option("--no-figure", is_flag=True, help="Write the JSON and the tracks only.")
def localise(log, map_file, psm_model, outdir, no_figure):
    """Estimate the track (x, y, heading) of a bench LOG from its currents alone.

    Each sample by maximum likelihood (Levenberg-Marquardt with the model's
    Jacobian, receivers weighted by the noise measured on the log), started
    from the previous sample's estimate and the first from the logged first
    pose; errors against the logged poses beside the Cramer-Rao bound, for
    the map and for the paper's PSM.

    Example: esense localise run.csv --map tank.map.npz -o loc/
    """
    from electrosense.validation.diagnosis.observations import DiagnosisInputError
    from electrosense.validation.localisation.from_log import localise_log

    psm = None
    if psm_model:
        from electrosense.validation.simulation.models import ModelError, _load_psm

        try:
            psm = _load_psm(psm_model)
        except ModelError as exc:
            raise click.BadParameter(str(exc), param_hint="--psm-model") from None
    try:
        s = localise_log(log, map_file, outdir, psm, figure=not no_figure, progress=lambda t: click.echo(f"  {t}"))
    except (ValueError, DiagnosisInputError) as exc:
        raise click.ClickException(str(exc)) from None
    for name in ("map", "psm"):
        m = s[name]
        crb = "no bound" if m["crb_position_rms_m"] is None else f"bound {1e3 * m['crb_position_rms_m']:.3f} mm"
        click.echo(f"{name.upper()}: position {1e3 * m['position_rms_m']:.3f} mm RMS ({crb}), heading "
                   f"{1e3 * m['heading_rms_rad']:.2f} mrad RMS, {m['estimated']} of {m['samples']} samples"
                   + (f"; {m['note']}" if m.get("note") else ""))
    click.echo(f"wrote {outdir}/localise.json")
