"""The validation report: metrics.json, the figures of each log, and the sections of index.html.

:func:`validation_sections` turns the results of
:func:`electrosense.validation.comparison.validate.validate_log` into figures (PNG) and
:class:`~validation.report.html.Section` objects; :func:`write_validation_report`
writes them with ``metrics.json`` into one folder. ``esense demo`` and the
paper-reproduction study add their own sections to the same page.

Example
-------
>>> paths = write_validation_report([result], "out")       # doctest: +SKIP
>>> sorted(p.name for p in paths.values())[:2]              # doctest: +SKIP
['index.html', 'metrics.json']
"""
from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Sequence

import numpy as np

from electrosense.validation.bench.log.header import describe_tank
from electrosense.validation.report.html import Figure, Section, Table, write_html

__all__ = ["validation_sections", "write_metrics_json", "write_validation_report", "metrics_dict", "log_figures"]

_PCT = "(%)"


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_") or "log"


def _summary_table(results) -> Table:
    from electrosense.validation.comparison.validate import validation_summary_rows

    return Table(
        ["log", "comparison", "mean abs. error (%)", "max abs. error (%)", "RMS (%)", "bias (%)", "samples"],
        validation_summary_rows(results),
        caption="Relative error of the receiver currents, all receivers: simulation / reference - 1 (positive: "
                "the simulation predicts more current)",
        digits=3,
    )


def _comparisons(result) -> list:
    """(label, comparison) for every model vs the bench, after the correction, and PSM vs BEM."""
    entries = [(f"{m.upper()} vs bench", result.comparisons[m]) for m in result.models]
    entries += [(f"{m.upper()} vs bench, sigma corrected", result.corrected[m]) for m in result.corrected]
    if result.model_difference is not None:
        entries.append(("PSM vs BEM", result.model_difference))
    return entries


def _receiver_table(result) -> Table:
    rows = []
    for name, c in _comparisons(result):
        for k, s in c.by_receiver.items():
            rows.append([name, int(k), 100 * s["mean_abs"], 100 * s["max_abs"], 100 * s["rms"], 100 * s["bias"]])
    return Table(["comparison", "receiver", "mean abs. (%)", "max abs. (%)", "RMS (%)", "bias (%)"], rows,
                 caption="Per receiver", digits=3)


def _region_table(result) -> Table:
    rows = []
    for name, c in _comparisons(result):
        for region, d in c.by_region.items():
            s = d["all"]
            rows.append([name, region, s["n"], 100 * s["mean_abs"], 100 * s["max_abs"], 100 * s["rms"], 100 * s["bias"]])
    t = result.thresholds_m
    return Table(
        ["comparison", "region", "samples", "mean abs. (%)", "max abs. (%)", "RMS (%)", "bias (%)"], rows,
        caption=(f"By region of the path (an electrode centre within {t.get('near_wall_m')} m of a tank boundary, "
                 f"or within {t.get('near_object_m')} m of an object's bounding sphere; otherwise mid-tank)"),
        digits=3,
    )


def _correction_table(result) -> Table | None:
    if not result.corrections:
        return None
    rows = []
    for m, fit in result.corrections.items():
        rows.append([m.upper(), fit.scale, 100 * fit.std_error, fit.percent, fit.sigma_nominal_S_per_m,
                     fit.sigma_effective_S_per_m, 100 * result.comparisons[m].overall["mean_abs"],
                     100 * result.corrected[m].overall["mean_abs"]])
    return Table(
        ["model", "scale s", "std. error (%)", "correction (%)", "sigma nominal (S/m)", "sigma effective (S/m)",
         "mean abs. error before (%)", "after (%)"],
        rows,
        caption="Conductivity correction: one factor s on the model's currents fitted to the bench (least squares "
                "on relative errors); std. error from a block jackknife over contiguous poses",
        digits=5,
    )


def log_figures(result, folder, potential: bool = True, potential_n: int = 81, potential_pose_index=None,
                edge_length_m=None) -> tuple[list[Figure], list[str]]:
    """Write the figures of one log into ``folder``; return them with notes on what was skipped.

    1. resistance U/I against position (bench, models, corrected bench);
    2. relative error against position (each model vs bench; PSM vs BEM dashed);
    3. mean abs. error by region (bars);
    4. the 3D scene with the path coloured by the error of the first model;
    5. the BEM potential on the mid-plane at one pose (default: the pose of
       largest error), with current lines.
    """
    from electrosense.meshes.pose import Pose
    from electrosense.meshes.render import RenderUnavailable
    from electrosense.validation.report.figures import (
        bar_figure,
        lateral_signal_figure,
        path_coordinate,
        potential_figure,
        relative_error_figure,
        resistance_figure,
        scene_figure,
    )
    from electrosense.validation.report.style import RELATIVE_ERROR_LABEL

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    log = result.log
    slug = _slug(result.label)
    passes = log.passes if len(log.pass_numbers) > 1 else None
    x, x_label = path_coordinate(log.poses, passes)
    receivers = result.receivers
    figures, notes = [], []
    U = log.U_V[:, None]
    models_ohm = {m: U / I for m, I in result.model_currents_A.items()}
    corrected = result.corrected_bench_A()
    first = result.models[0]
    p = resistance_figure(x, log.resistance_ohm, models_ohm, receivers, folder / f"resistance_{slug}.png",
                          corrected_bench_ohm=None if corrected is None else U / corrected, x_label=x_label,
                          passes=passes)
    corr_note = (f" The corrected bench is the bench divided by the {first.upper()} conductivity factor "
                 f"s = {result.corrections[first].scale:.4f}." if result.corrections else "")
    figures.append(Figure(p, f"{result.label}: resistance U/I of each receiver against position; bench (dots), "
                             f"models (lines){', one row per pass' if passes is not None else ''}.{corr_note}"))
    split, W = log.sensor.lateral_weights()
    if split:   # sectors: the lateral signal, left minus right, of each split electrode
        Wr = W[:, np.asarray(receivers) - 1]
        names = [f"electrode {j + 1} ({log.sensor.electrodes[j].sectors} sectors)" for j in split]
        p = lateral_signal_figure(x, log.currents_A @ Wr.T, {m: I @ Wr.T for m, I in result.model_currents_A.items()},
                                  names, folder / f"lateral_{slug}.png", x_label=x_label, passes=passes)
        figures.append(Figure(p, f"{result.label}: lateral signal of each split electrode, left minus right (the "
                                 "sectors' currents weighted by the cosine of their azimuth from the sensor's +y "
                                 "side, the left when the head points forward): bench (dots), models (lines). It "
                                 "changes sign with the side the nearest wall or object is on."))
    errors = {f"{m.upper()} / bench - 1": c.error for m, c in result.comparisons.items()}
    errors.update({f"{m.upper()} corrected / bench - 1": c.error for m, c in result.corrected.items()})
    if result.model_difference is not None:
        errors["PSM / BEM - 1"] = result.model_difference.error
    noise = _noise(result.comparisons[first].error, log)
    p = relative_error_figure(x, errors, receivers, folder / f"error_{slug}.png", x_label=x_label, passes=passes,
                              y_label=RELATIVE_ERROR_LABEL.replace("bench", "reference"), noise=noise)
    figures.append(Figure(p, f"{result.label}: relative error of the receiver currents, simulation / reference - 1 "
                             "in percent (positive: the simulation predicts more current); the reference is the "
                             "bench, or the BEM for PSM / BEM (dashed); the grey band is the bench's noise "
                             "(1 sigma, from the scatter along the path)."))
    regions = list(dict.fromkeys(result.comparisons[first].by_region))
    bars = {}
    for name, c in list(result.comparisons.items()) + ([("PSM / BEM", result.model_difference)]
                                                       if result.model_difference is not None else []):
        by = c.by_region
        label = name.upper() + " / bench" if name in result.comparisons else name
        bars[label] = [np.nan if by[r]["all"]["mean_abs"] is None else 100 * by[r]["all"]["mean_abs"]
                       for r in regions]
    counts = [int(result.comparisons[first].by_region[r]["all"]["n"]) for r in regions]
    p = bar_figure(regions, bars, folder / f"regions_{slug}.png", f"{result.label}: error by region of the path",
                   "mean |simulation / reference - 1| (%)", counts=counts,
                   lines={"noise (1 sigma)": 100 * noise} if noise else None)
    figures.append(Figure(p, f"{result.label}: mean absolute relative error by region of the path; n is the number "
                             "of samples (poses x receivers) in the region."))
    err = 100 * np.abs(result.comparisons[first].error).mean(axis=1)
    worst = int(np.argmax(err)) if potential_pose_index is None else int(potential_pose_index)
    pose = Pose.from_array(log.poses[worst])
    try:
        from electrosense.meshes.sensor_mesh import mesh_sensor

        sensor_mesh = mesh_sensor(log.sensor, edge_length_m=edge_length_m)
    except Exception as exc:  # the figure still shows the tank and the path
        sensor_mesh = None
        notes.append(f"sensor mesh not drawn: {exc}")
    object_meshes = []
    if result.objects:
        try:
            from electrosense.meshes.object_mesh import mesh_object

            object_meshes = [mesh_object(o) for o in result.objects]
        except Exception as exc:
            notes.append(f"objects not drawn: {exc}")
    try:
        p = scene_figure(folder / f"scene_{slug}.png", sensor_mesh, pose, log.tank, log.poses[:, :3], err,
                         value_label=f"{first.upper()} mean abs. error (%)", object_meshes=object_meshes,
                         title=f"{result.label}: path coloured by {first.upper()} error", passes=passes,
                         emitter=log.emitter, value_floor=0.0 if noise is None else 100 * noise)
        figures.append(Figure(p, f"{result.label}: the scene; the sensor is drawn at the pose of largest "
                                 f"{first.upper()} error (x = {pose.x_m:.3f} m), the path coloured by the "
                                 "mean abs. error over receivers (the scale starts at 0 and spans at least the "
                                 "noise level)."))
    except RenderUnavailable as exc:
        notes.append(f"3D scene left out: {exc}")
    if potential:
        try:
            from electrosense.validation.simulation.field import (
                electrode_seeds_xy,
                electrode_segments_xy,
                mid_plane_potential,
                sensor_outline_xy,
                tank_walls_xy,
            )

            U0 = float(log.U_V[worst])
            plane = mid_plane_potential(log.sensor, pose, log.tank, log.sigma_S_per_m, U_V=U0, n=potential_n,
                                        edge_length_m=edge_length_m, objects=result.objects)
            sensor = log.sensor
            spacing = float(np.diff(plane.x_m).max())
            seeds = electrode_seeds_xy(sensor, pose, sensor.emitter, offset_m=0.002 + 2.5 * spacing)
            walls = tank_walls_xy(log.tank, (plane.x_m[0], plane.x_m[-1]), (plane.y_m[0], plane.y_m[-1]),
                                  tolerance_m=1.5 * spacing)
            p = potential_figure(folder / f"potential_{slug}.png", plane.x_m, plane.y_m, plane.potential_V,
                                 sensor_outline_xy(sensor, pose), electrode_segments_xy(sensor, pose), seeds_m=seeds,
                                 walls_m=walls, emitter=sensor.emitter,
                                 title=f"BEM potential on the mid-plane, emitter at {U0:g} V, x = {pose.x_m:.3f} m")
            figures.append(Figure(p, f"{result.label}: BEM potential on the sensor's horizontal mid-plane at the "
                                     "pose of largest error, equipotentials and current lines from the emitter "
                                     f"(solved in {plane.seconds:.0f} s)."))
        except ImportError as exc:
            notes.append(f"potential figure skipped: the BEM field evaluation is not available ({exc})")
        except Exception as exc:  # a picture must not sink the report; say why it is missing
            notes.append(f"potential figure skipped: {type(exc).__name__}: {exc}")
    return figures, notes


def _noise(error, log) -> float | None:
    """The bench's relative noise (1 sigma) from the scatter of ``error`` (P, m) along each pass; None if too short."""
    from electrosense.validation.comparison.metrics import noise_level

    groups = [np.flatnonzero(np.asarray(log.passes) == p) for p in log.pass_numbers]
    if sum(max(len(g) - 2, 0) for g in groups) < 8:  # too few second differences for a spread
        return None
    try:
        return noise_level(np.asarray(error, dtype=float), groups)
    except ValueError:
        return None


def validation_sections(results: Sequence, folder, potential: bool = True, potential_n: int = 81,
                        edge_length_m=None, progress=None, potential_logs=None) -> list[Section]:
    """Sections of the page: a summary, then one per log (tables and figures).

    ``potential_logs``: draw the BEM potential figure (one BEM solve each) only for the first N logs (an
    int) or for the logs of these labels (a collection of str); ``None``: every log.
    """
    sections = [Section(
        "Summary",
        ["Receiver currents simulated at every logged pose and compared with the bench. Errors are relative, "
         "with one sign in every table and figure: simulation / bench - 1, and PSM / BEM - 1 for the models' "
         "difference on the same poses (positive: the simulation predicts more current). "
         "'mean abs.' is the paper's mean relative error."],
        tables=[_summary_table(results)],
    )]
    for i, r in enumerate(results):
        if potential_logs is None:
            draw = potential
        elif isinstance(potential_logs, int):
            draw = potential and i < potential_logs
        else:
            draw = potential and r.label in set(potential_logs)
        figures, notes = log_figures(r, folder, potential=draw, potential_n=potential_n,
                                     edge_length_m=edge_length_m)
        if progress is not None:
            progress.update(1)
        log = r.log
        tank = describe_tank(log.tank)
        text = [f"Sensor {log.sensor.name} (emitter {log.emitter}, receivers {', '.join(map(str, r.receivers))}), "
                f"{tank}, nominal conductivity {log.sigma_S_per_m:g} S/m; {len(log.poses)} poses in "
                f"{len(log.pass_numbers)} pass(es). Simulation time: "
                + ", ".join(f"{m.upper()} {s:.1f} s" for m, s in r.seconds.items()) + "."]
        tables = [_receiver_table(r), _region_table(r)]
        corr = _correction_table(r)
        if corr is not None:
            tables.insert(0, corr)
        notes = list(log.warnings) + notes
        sections.append(Section(f"Log {r.label}", text, tables=tables, figures=figures, notes=notes))
    return sections


def metrics_dict(results, extra: dict | None = None) -> dict:
    """The content of metrics.json."""
    from electrosense.validation.simulation.models import code_version

    d = {
        "generated_by": code_version(),
        "definitions": {
            "relative_error": "(model - reference) / reference of each receiver current; reference = bench, "
                              "or BEM for psm_vs_bem",
            "mean_abs": "mean of |relative error| (the paper's mean relative error)",
            "max_abs": "max of |relative error|",
            "rms": "sqrt(mean(relative error^2))",
            "bias": "mean of relative error (positive: the model predicts more current)",
            "units": "fractions (x100 for percent)",
        },
        "logs": [r.to_dict() for r in results],
    }
    if extra:
        d.update(extra)
    return d


def write_metrics_json(results, path, extra: dict | None = None) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(metrics_dict(results, extra), indent=2) + "\n")
    return path


def write_validation_report(results: Sequence, outdir, title: str = "electrosense validation",
                            extra_sections: Sequence[Section] = (), leading_sections: Sequence[Section] = (),
                            intro: str | Sequence[str] = "",
                            footer: str = "", potential: bool = True, potential_n: int = 81,
                            edge_length_m=None, extra_metrics: dict | None = None, progress=None,
                            potential_logs=None) -> dict:
    """Write metrics.json, the PNGs and index.html into ``outdir``; return their paths.

    ``leading_sections`` go before the validation's sections, ``extra_sections`` after.
    """
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    metrics = write_metrics_json(results, outdir / "metrics.json", extra_metrics)
    sections = validation_sections(results, outdir, potential, potential_n, edge_length_m, progress, potential_logs)
    sections = list(leading_sections) + sections + list(extra_sections)
    page = write_html(outdir / "index.html", title, sections, intro=intro, footer=footer)
    return {"metrics": metrics, "index": page, "figures": sorted(outdir.glob("*.png"))}
