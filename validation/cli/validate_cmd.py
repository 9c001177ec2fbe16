"""``esense validate``: BEM and PSM against logged bench currents, with a report.

Example::

    esense validate run1.csv run2.csv --models bem,psm --conductivity-correction -o report/

writes ``report/metrics.json`` (errors per model, receiver and region of the
path, the PSM-BEM difference, the conductivity correction), the figures as
PNG, and ``report/index.html``, a static page readable offline.
"""
from __future__ import annotations

from pathlib import Path

import click

from electrosense.validation.cli._parsing import finite_float


def _parse_models(text: str) -> tuple[str, ...]:
    from electrosense.validation.comparison.validate import MODEL_ORDER

    models = tuple(dict.fromkeys(m.strip().lower() for m in text.split(",") if m.strip()))
    bad = [m for m in models if m not in MODEL_ORDER]
    if bad or not models:
        raise click.BadParameter(f"{text!r}: expected a comma-separated list of {', '.join(MODEL_ORDER)}",
                                 param_hint="--models")
    return models


def _without_the_psm(model_names: tuple, named: bool, logs: list, why: str) -> tuple:
    """``model_names`` without the PSM where ``logs`` hold what it cannot simulate (``why``): said, or refused where
    ``--models`` named it (``named``)."""
    if not logs or "psm" not in model_names:
        return model_names
    if named:
        raise click.BadParameter(f"{', '.join(logs)}: {why}: leave psm out of --models", param_hint="--models")
    kept = tuple(m for m in model_names if m != "psm")
    click.echo(f"note: {', '.join(logs)}: {why}: comparing with the {' and the '.join(m.upper() for m in kept)} only",
               err=True)
    return kept


def objects_of_log(log, objects=(), tank_map=None) -> tuple:
    """The objects in the tank of ``log``: those given (a scene file), else those its meta line lists (``esense
    sweep`` of a scene), else the tank map's fixed objects."""
    from electrosense.validation.bench.log.header import logged_objects

    return tuple(objects) or logged_objects(log.meta, getattr(log, "path", "")) or tuple(getattr(tank_map, "objects", ()))


def validate_logs(logs, models, psm=None, conductivity_correction=False, objects=(), stride=1, near_wall_m=None,
                  near_object_m=None, edge_length_m=None, show_progress=True, bar=None, tank_map=None):
    """Validate already-read logs (BenchLog objects); return the list of LogValidation results.

    ``psm``: a PSM (object or JSON path) for every log, a dict sensor name -> PSM, or None (calibrated, cached).
    ``tank_map``: the map (object or file) that model ``"map"`` evaluates (no BEM).
    Shared by ``esense validate`` and ``esense demo``.
    """
    from electrosense.validation.comparison import NEAR_OBJECT_M, NEAR_WALL_M
    from electrosense.validation.comparison.validate import validate_log
    from electrosense.validation.simulation.models import EvaluatorCache

    bem_options = {} if edge_length_m is None else {"edge_length_m": edge_length_m}
    evaluators = EvaluatorCache(psm_model=psm, tank_map=tank_map, **bem_options)
    results = []
    for log in logs:
        if stride > 1:
            log = _every(log, stride)
        results.append(validate_log(
            log, models, conductivity_correction=conductivity_correction,
            objects=objects_of_log(log, objects, tank_map),
            near_wall_m=NEAR_WALL_M if near_wall_m is None else near_wall_m,
            near_object_m=NEAR_OBJECT_M if near_object_m is None else near_object_m,
            evaluators=evaluators, progress=show_progress and "bem" in models,
            label=_label(log, results), **bem_options))
        if bar is not None:
            bar.update(len(models))
    return results


def run_validation(logs, models, outdir, psm=None, conductivity_correction=False, objects=(), stride=1,
                   near_wall_m=None, near_object_m=None, potential=True, potential_n=81, edge_length_m=None,
                   title="electrosense validation", footer="", show_progress=True, tank_map=None):
    """Validate logs and write the report (metrics.json, PNGs, index.html) into ``outdir``; return (results, paths)."""
    from tqdm.auto import tqdm

    from electrosense.validation.comparison.report import write_validation_report

    with tqdm(total=len(logs) * (len(models) + 1), desc="validate", unit="step", disable=not show_progress) as bar:
        results = validate_logs(logs, models, psm, conductivity_correction, objects, stride, near_wall_m,
                                near_object_m, edge_length_m, show_progress, bar, tank_map)
        bar.set_description("figures")
        paths = write_validation_report(results, outdir, title=title, footer=footer, potential=potential,
                                        potential_n=potential_n, edge_length_m=edge_length_m, progress=bar)
    return results, paths


def _label(log, earlier) -> str:
    stem = Path(log.path).stem if log.path is not None else "log"
    used = {r.label for r in earlier}
    label, k = stem, 2
    while label in used:
        label, k = f"{stem}-{k}", k + 1
    return label


def _every(log, stride: int):
    """Every ``stride``-th sample of each pass (the log's own rows, unchanged)."""
    from electrosense.validation.bench.log import BenchLog

    keep = []
    for p in log.pass_numbers:
        rows = [i for i, q in enumerate(log.passes) if q == p]
        keep += rows[::stride]
    keep.sort()
    return BenchLog(log.meta, log.data.iloc[keep].reset_index(drop=True), log.sensor, log.tank, log.sigma_S_per_m,
                    log.emitter, list(log.warnings) + [f"validated every {stride}th sample of each pass"],
                    log.path, log.paths)


def print_summary(results, paths, echo=click.echo) -> None:
    from electrosense.validation.comparison.validate import validation_summary_rows

    echo(f"{'log':<24} {'comparison':<32} {'mean %':>8} {'max %':>8} {'RMS %':>8} {'bias %':>8}")
    for row in validation_summary_rows(results):
        echo(f"{row[0]:<24} {row[1]:<32} {row[2]:8.3f} {row[3]:8.3f} {row[4]:8.3f} {row[5]:+8.3f}")
    for r in results:
        for m, fit in r.corrections.items():
            echo(f"{r.label}: conductivity correction ({m.upper()}) s = {fit.scale:.5f} +- {fit.std_error:.5f} "
                 f"({fit.percent:+.2f} %), sigma {fit.sigma_nominal_S_per_m:g} -> {fit.sigma_effective_S_per_m:.5g} S/m")
    echo(f"metrics: {paths['metrics']}")
    echo(f"report:  {paths['index']}")


@click.command("validate")
@click.argument("logs", nargs=-1, required=True, type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--models", default=None,
              help="Models to compare with the bench, comma-separated (bem, psm, map); default bem,psm, or map,psm "
                   "with --map.")
@click.option("--map", "map_file", type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="Tank map of the logs' sensor, tank and depth (esense map build): model 'map', the BEM without "
                   "new BEM solves.")
@click.option("--psm", "psm_file", type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="PSM model file (JSON from `esense calibrate`); default: calibrate on the free-space BEM (cached).")
@click.option("--conductivity-correction", is_flag=True,
              help="Fit the paper's one-factor conductivity correction per model and report every metric after it.")
@click.option("--scene", "scene_file", type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="Scene file (TOML) whose objects are in the tank during the logs (simulated, and used for "
                   "the 'near an object' region); default: the objects each log's meta line lists, else the map's.")
@click.option("--edge-length", type=finite_float(positive=True), default=None,
              help="BEM sensor mesh edge length far from the electrode edges (m); default: the mesher's.")
@click.option("--stride", type=click.IntRange(min=1), default=1, show_default=True,
              help="Validate every N-th sample of each pass (faster BEM runs on long logs).")
@click.option("--near-wall", type=finite_float(positive=True), default=None,
              help="Region threshold: an electrode centre this close to a tank boundary is 'near' it (m, default 0.1).")
@click.option("--near-object", type=finite_float(positive=True), default=None,
              help="Region threshold: an electrode centre this close to an object is 'near' it (m, default 0.1).")
@click.option("--no-potential", is_flag=True, help="Skip the BEM potential figure (one extra BEM solve).")
@click.option("-o", "--out", "outdir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Output folder: metrics.json, index.html and the PNG figures.")
@click.option("--quiet", is_flag=True, help="No progress bars.")
def validate(logs, models, map_file, psm_file, conductivity_correction, scene_file, edge_length, stride, near_wall,
             near_object, no_potential, outdir, quiet):
    """Compare BEM and PSM receiver currents with bench LOGS (bench-log CSV files); write a report to OUTDIR."""
    from electrosense.validation.cli.transfer_logs import (  # transfer logs: their own comparison
        all_transfer_logs,
        run_transfer_logs,
    )

    if all_transfer_logs(logs):
        return run_transfer_logs(logs, outdir, positions=False)
    import sys

    from electrosense.meshes.render import offscreen_backend
    from electrosense.psm.images import has_images
    from electrosense.validation.bench.log import BenchLogError, read_bench_log

    model_names = _parse_models(models or ("map,psm" if map_file else "bem,psm"))
    tank_map = None
    if ("map" in model_names) != bool(map_file):
        raise click.BadParameter("model map and --map FILE go together", param_hint="--map")
    if map_file:
        from electrosense.validation.cli._parsing import map_option

        tank_map = map_option(map_file)
    try:
        read = [read_bench_log(p) for p in logs]
    except BenchLogError as exc:
        raise click.ClickException(str(exc)) from None
    for log in read:
        for w in log.warnings:
            click.echo(f"warning: {log.path.name}: {w}", err=True)
    objects = ()
    if scene_file is not None:
        from electrosense.meshes.scene_file import load_scene

        try:
            objects = tuple(load_scene(scene_file).objects)
        except ValueError as exc:
            raise click.ClickException(f"{scene_file}: {exc}") from None
    from electrosense.validation.diagnosis.forward import effect_objects

    curved = [log.path.name for log in read if not has_images(log.tank)]
    model_names = _without_the_psm(model_names, models is not None, curved,
                                   "a cylindrical tank, which the PSM (a box's images) cannot simulate")
    in_tank = {log.path.name: objects_of_log(log, objects, tank_map) for log in read}
    not_balls = [name for name, objs in in_tank.items() if len(effect_objects(objs)) < len(objs)]
    model_names = _without_the_psm(model_names, models is not None, not_balls,
                                   "a pole or a box in the tank, which the PSM (a ball's object term) cannot simulate")
    if tank_map is not None and not objects and tank_map.objects:   # validate_logs: the map's, where a log lists none
        click.echo(f"note: the map's {len(tank_map.objects)} fixed object(s) stand in the tank of every log that "
                   "lists none", err=True)
    if psm_file is not None and "psm" not in model_names:
        raise click.BadParameter("--psm is given but psm is not among --models", param_hint="--psm")
    if offscreen_backend() is None:  # EGL or OSMesa, chosen once for every picture
        click.echo("note: no offscreen OpenGL (EGL or OSMesa) here: the report leaves out its 3D pictures", err=True)
    try:
        results, paths = run_validation(
            read, model_names, outdir, psm=psm_file, conductivity_correction=conductivity_correction,
            objects=objects, stride=stride, near_wall_m=near_wall, near_object_m=near_object,
            potential=not no_potential and "bem" in model_names, edge_length_m=edge_length,
            footer="esense " + " ".join(sys.argv[1:]), show_progress=not quiet, tank_map=tank_map)
    except ValueError as exc:  # model errors, impossible scenes: say what and stop
        raise click.ClickException(str(exc)) from None
    print_summary(results, paths)
