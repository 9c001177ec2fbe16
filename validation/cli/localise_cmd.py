"""``esense localise``: the robot's track from its currents alone, by a tank map and by the PSM, with their bounds."""
from __future__ import annotations

import math

import click

from electrosense.validation.cli._parsing import finite_float
from electrosense.validation.localisation.smoother import MotionModel


@click.command("localise")
@click.argument("log", type=click.Path(exists=True, dir_okay=False))
@click.option("--map", "map_file", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Tank map of the log's sensor, tank and depth (esense map build).")
@click.option("--psm-model", type=click.Path(exists=True, dir_okay=False), default=None,
              help="PSM JSON for the comparison (default: the one calibrated on the sensor's free-space BEM).")
@click.option("-o", "--out", "outdir", required=True, type=click.Path(file_okay=False),
              help="Output folder: localise.json, localise.png, localise_tracks.npz.")
@click.option("--no-figure", is_flag=True, help="Write the JSON and the tracks only.")
@click.option("--acceleration-psd", type=finite_float(positive=True), default=MotionModel.acceleration_psd_m2_per_s3,
              show_default=True, metavar="M2/S3",
              help="Motion prior: spectral density of the robot's unplanned acceleration in x and y (the square of "
                   "the speed change, m/s, it makes in a second unplanned); the default is a bench's cartesian robot.")
@click.option("--turn-psd", type=finite_float(positive=True), default=MotionModel.turn_psd_rad2_per_s3,
              show_default=True, metavar="RAD2/S3", help="Motion prior: the same for the heading.")
@click.option("--per-sample", is_flag=True,
              help="No motion prior: each sample by maximum likelihood on its own currents (the per-sample bound).")
@click.option("--noise", type=finite_float(positive=True), default=None, metavar="REL",
              help="Relative noise of a current (1 sigma) instead of the one measured on the log.")
@click.option("--no-object", is_flag=True, help="Do not look for an object the log passes.")
@click.option("--object-z", type=finite_float(), default=None, metavar="Z",
              help="Height of the object's centre (m, tank frame); default: the log's depth.")
@click.option("--object-at", default=None, metavar="X,Y[,Z]",
              help="The object's true centre (m, tank frame), to score the estimate against.")
def localise(log, map_file, psm_model, outdir, no_figure, acceleration_psd, turn_psd, per_sample, noise, no_object,
             object_z, object_at):
    """Estimate the track (x, y, heading) of a bench LOG from its currents alone.

    By default the most probable track over each pass under a motion prior
    (nearly constant velocity, white-noise acceleration of the given
    spectral densities): Gauss-Newton on all poses at once with the model's
    Jacobian, each step a Kalman filter and Rauch-Tung-Striebel smoother, so
    that where the currents fix the position (near corners) it holds along
    the pass. Receivers are weighted by the noise measured on the log;
    errors against the logged poses beside the posterior Cramer-Rao bound
    (and the per-sample one), for the map and for the paper's PSM.

    Then an object the log passes: one sphere fitted to the currents at the
    logged poses (its change of K from the BEM's field on the map's
    currents, and the PSM's), reported where it is detected at a 1 %
    false-alarm rate, with its Cramer-Rao bound (--object-at scores it).

    Example: esense localise run.csv --map tank.map.npz -o loc/
    """
    from electrosense.validation.diagnosis.observations import DiagnosisInputError
    from electrosense.validation.localisation.from_log import localise_log

    motion = None if per_sample else MotionModel(acceleration_psd, turn_psd)
    true_object = None
    if object_at is not None:
        try:
            true_object = [float(v) for v in object_at.split(",")]
        except ValueError:
            true_object = []
        if len(true_object) not in (2, 3) or not all(map(math.isfinite, true_object)):
            raise click.BadParameter(f"{object_at!r}: give the centre as X,Y or X,Y,Z in metres",
                                     param_hint="--object-at")
    psm = None
    if psm_model:
        from electrosense.validation.simulation.models import ModelError, _load_psm

        try:
            psm = _load_psm(psm_model)
        except ModelError as exc:
            raise click.BadParameter(str(exc), param_hint="--psm-model") from None
    try:
        s = localise_log(log, map_file, outdir, psm, figure=not no_figure, motion=motion, noise_rel=noise,
                         progress=lambda t: click.echo(f"  {t}"), find_object=not no_object, object_z_m=object_z,
                         true_object_m=true_object)
    except (ValueError, DiagnosisInputError) as exc:
        raise click.ClickException(str(exc)) from None
    for name in ("map", "psm"):
        m = s[name]
        if "left_out" in m:
            click.echo(f"{name.upper()}: left out ({m['left_out']})")
            continue
        crb = "no bound" if m["crb_position_rms_m"] is None else f"bound {1e3 * m['crb_position_rms_m']:.3f} mm"
        if m.get("expected_position_rms_m") is not None:
            crb += f", this estimator's expected error on the logged track {1e3 * m['expected_position_rms_m']:.3f} mm"
        click.echo(f"{name.upper()}: position {1e3 * m['position_rms_m']:.3f} mm RMS ({crb}), heading "
                   f"{1e3 * m['heading_rms_rad']:.2f} mrad RMS, {m['estimated']} of {m['samples']} samples"
                   + (f"; {m['note']}" if m.get("note") else ""))
        if "distance_from_axis_rms_m" in m:
            click.echo(f"  round tank: distance from the axis {1e3 * m['distance_from_axis_rms_m']:.3f} mm RMS, heading "
                       f"against the radius {1e3 * m['heading_against_radius_rms_rad']:.2f} mrad RMS ({m['round_tank']})")
    from electrosense.validation.localisation.object_position import describe

    for name in ("map", "psm"):
        if "object" in s and name in s["object"]:
            click.echo(f"{name.upper()} object: {describe(s['object'][name])}")
        elif "object" in s and f"{name}_left_out" in s["object"]:
            click.echo(f"{name.upper()} object: left out ({s['object'][name + '_left_out']})")
    click.echo(f"wrote {outdir}/localise.json")

