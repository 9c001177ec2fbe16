"""``esense calibrate``: fit the poly-spherical model to a free-space conductance matrix."""
from __future__ import annotations

import click

from electrosense.validation.cli._parsing import finite_float, sensor_option


@click.command("calibrate")
@click.option("--reference", "reference_path", type=click.Path(exists=True, dir_okay=False),
              help="Conductance matrix JSON as written by `esense conductance --json` (free space).")
@click.option("--paper-table", is_flag=True, help="Fit the paper's printed S_BEM of the 4-electrode sensor instead.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Where to write the model (psm.json).")
@click.option("--symmetric", is_flag=True, help="The paper's symmetry: mirror-equal radii and centre distances.")
@click.option("--fix-length", "fix_length_m", type=finite_float(positive=True), default=None,
              help="Fix the distance between the outermost sphere centres (m), e.g. 0.2 for the 2-electrode sensor.")
@click.option("--sensor", default=None,
              help="Sensor preset or file of the real sensor, to record its electrode areas (for the contact impedance); "
                   "default: the reference's own sensor when it names a preset.")
@click.option("--sigma", "sigma_S_per_m", type=finite_float(positive=True), default=None,
              help="Conductivity (S/m) for --paper-table (default: the paper's measured 0.0354 S/m).")
def calibrate(reference_path, paper_table, output, symmetric, fix_length_m, sensor, sigma_S_per_m):
    """Fit the PSM's radii and centre distances on the paper's criterion (17) and write psm.json.

    Example: ``esense calibrate --paper-table --symmetric -o psm.json``.
    The output holds radii_m, centres_m (sensor frame, electrode 1 at the
    head), emitter, gamma_criterion, the reference, and the fitted
    parameters with their uncertainties and correlations.
    """
    import json

    from electrosense.bem.conductance import ConductanceMatrix
    from electrosense.meshes.sensor import SensorDescription, load_sensor
    from electrosense.psm.calibration import CalibrationError
    from electrosense.psm.calibration import calibrate as fit
    from electrosense.psm.paper import SIGMA_MEASURED_S_PER_M, paper_reference

    if bool(reference_path) == bool(paper_table):
        raise click.UsageError("give exactly one of --reference S.json or --paper-table")
    if paper_table:
        ref = paper_reference(sigma_S_per_m or SIGMA_MEASURED_S_PER_M)
    else:
        try:
            with open(reference_path) as fh:
                ref = ConductanceMatrix.from_json_dict(json.load(fh))
        except (ValueError, OSError) as exc:
            raise click.ClickException(f"{reference_path}: {exc}") from None
    sensor_desc = None
    if sensor:
        sensor_desc = sensor_option(sensor)
    else:  # the reference's own sensor: a preset name or a full description
        own = ref.info.get("sensor")
        try:
            sensor_desc = load_sensor(own) if isinstance(own, str) else SensorDescription.from_dict(own) if isinstance(own, dict) else None
        except ValueError:
            sensor_desc = None
        if sensor_desc is not None and sensor_desc.n_electrodes != ref.n:
            sensor_desc = None
    try:
        cal = fit(ref, symmetric=symmetric, fix_length_m=fix_length_m, sensor=sensor_desc)
    except CalibrationError as exc:
        raise click.ClickException(str(exc)) from None
    cal.model.save(output)
    click.echo(cal.summary())
    click.echo(f"wrote {output}")
