"""``esense diagnose``: where the sim-to-real gap lies, which unmodelled effect causes it, how far it shrinks."""
from __future__ import annotations

import click

from electrosense.validation.diagnosis.effects import EFFECT_NAMES


@click.command("diagnose")
@click.argument("logs", nargs=-1, required=True, type=click.Path(exists=True, dir_okay=False))
@click.option("--model", type=click.Choice(["anchored", "bem", "psm"]), default="anchored", show_default=True,
              help="Baseline simulation of the logged poses. 'anchored': the BEM at as many poses as it takes for "
                   "its interpolation over pose (as a ratio to the PSM or to the free-space K, whichever "
                   "cross-validates better) to reach an estimated error below a third of the noise (BEM runs "
                   "cached on disk per sensor and tank); 'bem': the BEM "
                   "at every pose; 'psm': the bare calibrated PSM (its own error is then unknown). Geometric effects "
                   "are evaluated with that PSM for 'psm', with the PSM whose spheres sit at the electrodes (plus "
                   "Kelvin images for spheres) otherwise.")
@click.option("--effects", default="all", show_default=True,
              help=f"Candidates to consider: 'all' or a comma list of {', '.join(EFFECT_NAMES)}.")
@click.option("-o", "--out", "outdir", required=True, type=click.Path(file_okay=False),
              help="Output folder: diagnosis.json and index.html with figures.")
@click.option("--psm-model", type=click.Path(exists=True, dir_okay=False), default=None,
              help="PSM JSON to use instead of the one calibrated on the sensor's free-space BEM.")
@click.option("--edge-length", "edge_length_m", type=float, default=None,
              help="BEM sensor mesh edge length (m) for --model bem (default: the mesher's).")
@click.option("--split-poses", type=int, default=0, show_default=True,
              help="With --model psm: run the BEM on this many poses to split the gap into the PSM's approximation "
                   "and the physics the BEM lacks (0: skip).")
@click.option("--bem-correction", "bem_correction_poses", type=click.IntRange(min=0), default=0, show_default=True,
              help="With --model psm: run the BEM on about this many poses (dense near the walls) and correct the PSM "
                   "baseline by the BEM/PSM ratio interpolated along the path, so that the PSM's own approximation "
                   "is not taken for physics (0: the bare PSM).")
@click.option("--max-effects", type=click.IntRange(1, 3), default=3, show_default=True,
              help="Largest number of effects combined by the forward selection.")
@click.option("--model-error", type=float, default=0.0, show_default=True,
              help="Relative error of the effect model on what the tank does; samples where the tank matters most "
                   "(close to the walls) are weighted down accordingly (0: equal weights).")
@click.option("--no-figures", is_flag=True, help="Write diagnosis.json and a page without figures.")
@click.option("--pdf", "vector_pdf", is_flag=True, help="A vector PDF beside each figure's PNG, for a paper.")
@click.option("--map", "map_file", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Tank map of the logs' sensor, tank and depth (esense map build): the baseline is the map at the "
                   "logged poses, with its estimated error; no new BEM.")
def diagnose(logs, model, effects, outdir, psm_model, edge_length_m, split_poses, bem_correction_poses, max_effects,
             model_error, no_figures, vector_pdf, map_file):
    """Diagnose the gap between bench LOG(s) and the simulation.

    Fits every candidate effect (conductivity, temperature_drift,
    contact_impedance, channel_gain, pose_offset, water_depth, tank_size,
    unmodelled_object) on part of the data and scores it on the rest; chooses
    up to three by forward selection, or 'none' when the gap is at the noise
    level. Told nothing but what the logs say.

    Example: esense diagnose run.csv -o diag/
    """
    from electrosense.validation.cli.transfer_logs import (  # transfer logs: their own diagnosis
        all_transfer_logs,
        run_transfer_logs,
    )

    if all_transfer_logs(logs):
        return run_transfer_logs(logs, outdir, positions=True)
    from electrosense.validation.diagnosis.observations import DiagnosisInputError, from_bench_logs
    from electrosense.validation.diagnosis.pipeline import diagnose as run_diagnosis
    from electrosense.validation.diagnosis.pipeline import parse_effects
    from electrosense.validation.diagnosis.report import write_report
    from electrosense.validation.diagnosis.select import SelectionRules

    try:
        from electrosense.validation.bench.log import read_bench_log
    except ImportError as exc:  # pragma: no cover - the reader is part of the project
        raise click.ClickException(f"the bench-log reader is not available: {exc}") from None
    try:
        names = parse_effects(effects)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--effects") from None
    try:
        obs = from_bench_logs([read_bench_log(p) for p in logs])
    except (ValueError, DiagnosisInputError) as exc:
        raise click.ClickException(str(exc)) from None
    base_options = {"edge_length_m": edge_length_m} if (edge_length_m and (model != "psm" or bem_correction_poses
                                                                           or split_poses)) else {}
    baseline = None
    if map_file:
        from electrosense.validation.cli._parsing import map_option
        from electrosense.validation.diagnosis.map_baseline import map_baseline

        if model != "anchored":
            raise click.BadParameter(f"--map is the baseline; it does not go with --model {model}", param_hint="--map")
        from electrosense.validation.simulation.tank_map import log_in_map_scene

        try:
            tank_map = map_option(map_file)
            obs = log_in_map_scene(tank_map, obs)   # the map's fixed objects where the log lists none
            baseline = map_baseline(obs, tank_map)
        except ValueError as exc:
            raise click.BadParameter(str(exc), param_hint="--map") from None
        model = "map"
    click.echo(f"{obs.n_poses} samples, {len(set(obs.passes.tolist()))} pass(es); baseline {model}")
    from electrosense.validation.diagnosis.forward import effect_objects

    left_out = [f"{i} ({o.label})" for i, o in enumerate(obs.objects, start=1) if o not in effect_objects(obs.objects)]
    if left_out and model == "psm":   # the baseline itself is the PSM
        raise click.BadParameter(f"the PSM cannot hold object(s) {', '.join(left_out)} (its object term is a ball's): "
                                 "diagnose with --model anchored (the BEM) or --map", param_hint="--model")
    if left_out:
        click.echo(f"note: object(s) {', '.join(left_out)} in the baseline, left out of the effect model (the PSM's: "
                   "balls only), whose changes are computed without them")
    d = run_diagnosis(obs, model=model, effects=names, model_options=base_options,
                      rules=SelectionRules(max_effects=max_effects), split_with_bem=split_poses, psm_model=psm_model,
                      model_error=model_error, bem_correction_poses=bem_correction_poses,
                      progress=lambda s: click.echo(f"  {s}"), baseline=baseline)
    page = write_report(d, outdir, figures=not no_figures, vector="pdf" if vector_pdf else None)
    base = d.model_error.get("baseline_rms")
    click.echo(f"noise {100 * d.noise:.3f} %, baseline error "
               f"{'unknown' if base is None else f'{100 * base:.3f} %'}, noise floor {100 * d.noise_floor:.3f} %; "
               f"gap {100 * d.gap_before:.3f} % -> {100 * d.gap_after:.3f} % (held-out)")
    click.echo(f"verdict: {d.selection.verdict}; chosen: {', '.join(d.chosen) or '(nothing)'}")
    for a in d.ambiguity[:4]:
        click.echo(f"  as good as {d.chosen[0] if d.chosen else '?'}: {a['effect']} "
                   f"({100 * a['heldout_gap']:.3f} %); to separate: {a['separate_by']}")
    for p in d.confusable[:5]:
        click.echo(f"  cannot tell apart {p['pair'][0]} / {p['pair'][1]} ({p['angle_deg']:.1f} deg): {p['separate_by']}")
    click.echo(f"wrote {page} and {page.parent / 'diagnosis.json'} ({d.seconds:.1f} s)")
