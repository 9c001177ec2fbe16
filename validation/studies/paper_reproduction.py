"""Reproduce the paper's comparisons: angels-2 and angels-4, wall to wall at y = 0, 0.0354 S/m.

For each sensor:

1. the free-space BEM conductance of the real geometry, and the PSM
   calibrated on it (angels-2: one radius, length fixed to the real 20 cm;
   angels-4: the paper's symmetric layout), beside the paper's parameters;
2. a virtual-bench log of the wall-to-wall pass (by default the bundled
   ``<sensor>_wall-to-wall.csv``; ``--bench-model bem`` makes one here with
   the BEM as the physics);
3. BEM and PSM at the logged poses: the PSM-BEM mean relative error (paper:
   0.22 % and 0.97 %), bench against PSM before the correction (paper: 2.06 %
   and 2.37 %), the fitted conductivity correction (paper: about -2 %) and
   the error after it;
4. a report (``--out``, default ``paper-reproduction/``) whose figures are
   drawn on the paper's axes (its figures 6 to 8: x in m, U/I in ohm; PSM
   solid, BEM dashed, bench dots, corrected bench squares).

The PSM runs at every logged pose; the BEM (one solve per pose) at
``--bem-poses`` poses spread along the path, on which the BEM-PSM figure is
computed.

Run: ``python -m electrosense.validation.studies.paper_reproduction [--quick] [--bem-poses 41] [--out DIR]``.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from electrosense.psm.paper import SIGMA_MEASURED_S_PER_M

SIGMA_S_PER_M = SIGMA_MEASURED_S_PER_M  # the paper's tank water

#: The paper's figures (Jawad et al.), see docs/psm-model.md.
PAPER = {
    "angels-2": {"psm_vs_bem": 0.0022, "bench_vs_psm": 0.0206, "correction": -0.0206,
                 "parameters_cm": {"a": 0.71, "L": 20.0}, "R_axis_ohm": (600.0, 800.0),
                 "x_windows_m": [(-0.4, 0.4)], "figure": "figures 6 and 7"},
    "angels-4": {"psm_vs_bem": 0.0097, "bench_vs_psm": 0.0237, "correction": -0.0237,
                 "parameters_cm": {"a_e": 0.72, "a_i": 0.74, "L_e": 7.85, "L_i": 7.69}, "gamma": 4.48e-5,
                 "R_axis_ohm": (900.0, 1600.0), "x_windows_m": [(-0.38, -0.28), (0.28, 0.38)], "figure": "figure 8"},
}

#: The paper's line colours of receivers 1, 2, 3 (blue, red, green).
PAPER_RECEIVER_COLOURS = ("#1f5fbf", "#d62728", "#2ca02c")


def calibrate_like_the_paper(sensor, edge_length_m=None):
    """Free-space BEM of the sensor at 1 S/m and the PSM fitted to it the paper's way; (reference, calibration)."""
    from electrosense.psm import calibrate
    from electrosense.validation.simulation.models import free_space_bem

    reference = free_space_bem(sensor, edge_length_m)
    calibration = calibrate(reference, symmetric=True, sensor=sensor,
                            fix_length_m=sensor.length_m if sensor.n_electrodes == 2 else None)
    return reference, calibration


def _bem_subset(log, n: int) -> np.ndarray:
    """Indices of about ``n`` poses spread along the path (the first and the last included)."""
    P = len(log)
    return np.unique(np.round(np.linspace(0, P - 1, min(n, P))).astype(int))


def _subset_log(log, rows):
    from electrosense.validation.bench.log import BenchLog

    return BenchLog(log.meta, log.data.iloc[rows].reset_index(drop=True), log.sensor, log.tank, log.sigma_S_per_m,
                    log.emitter, list(log.warnings), log.path, log.paths)


def make_bem_bench_log(sensor, path: Path, n: int, edge_length_m=None, seed: int = 7) -> Path:
    """A wall-to-wall virtual-bench log with the BEM as the physics, conductivity -2.06 % (2 el.) / -2.37 % (4 el.)."""
    from electrosense.meshes.tank import Tank
    from electrosense.validation.bench.log import write_bench_log
    from electrosense.validation.bench.log.writer import bench_log_table
    from electrosense.validation.bench.virtual.bench import VirtualBench
    from electrosense.validation.bench.virtual.effects import Effects
    from electrosense.validation.bench.virtual.trajectory import wall_to_wall

    effect = PAPER[sensor.name]["correction"]
    tank = Tank((1.0, 1.0, 1.0))
    options = {} if edge_length_m is None else {"edge_length_m": edge_length_m}
    bench = VirtualBench(sensor, tank, SIGMA_S_PER_M, model="bem", effects=Effects(conductivity_rel=effect),
                         seed=seed, **options)
    run = bench.run(wall_to_wall(tank.size_m, n=n))
    data = bench_log_table(run.poses, run.U_V, run.currents_A, sensor.receivers, t_s=run.t_s)
    meta = {"sensor": sensor.name, "emitter": sensor.emitter, "tank_m": list(tank.size_m),
            "sigma_S_per_m": SIGMA_S_PER_M, "source": bench.describe()}
    return write_bench_log(path, meta, data, overwrite=True)


def paper_axes_figure(name, x_psm, R_psm, x_bem, R_bem, x_bench, R_bench, R_corrected, receivers, png_path):
    """Our curves on the paper's axes (PSM solid, BEM dashed, bench dots, corrected bench squares)."""
    from electrosense.validation.report.figures import Panel, Series, curves_figure

    paper = PAPER[name]
    panels = []
    for lo_x, hi_x in paper["x_windows_m"]:
        series = []
        for j, k in enumerate(receivers):
            colour = PAPER_RECEIVER_COLOURS[j % len(PAPER_RECEIVER_COLOURS)]
            tag = f" R{k}" if len(receivers) > 1 else ""
            first = j == 0
            inside = (x_psm >= lo_x - 1e-9) & (x_psm <= hi_x + 1e-9)
            series.append(Series(x_psm[inside], R_psm[inside, j], f"PSM{tag}", "line", colour))
            inside = (x_bem >= lo_x - 1e-9) & (x_bem <= hi_x + 1e-9)
            series.append(Series(x_bem[inside], R_bem[inside, j], f"BEM{tag}", "line", colour, style="--"))
            inside = (x_bench >= lo_x - 1e-9) & (x_bench <= hi_x + 1e-9)
            series.append(Series(x_bench[inside], R_bench[inside, j], "bench" if first else "", "scatter", colour,
                                 marker_size=5, marker="o"))
            series.append(Series(x_bench[inside], R_corrected[inside, j], "bench corrected" if first else "",
                                 "scatter", colour, marker_size=7, marker="s"))
        ys = np.concatenate([s.y for s in series if s.y.size])
        lo_y, hi_y = paper["R_axis_ohm"]
        y_range = (min(lo_y, float(ys.min())), max(hi_y, float(ys.max())))
        panels.append(Panel(f"{name}: x in [{lo_x:g}, {hi_x:g}] m (the paper's {paper['figure']})",
                            "position of the sensor x (m)", "resistance U/I (ohm)", series,
                            x_range=(lo_x, hi_x), y_range=(y_range[0], y_range[1] + 0.35 * (y_range[1] - y_range[0])),
                            legend_loc="upper centre"))
    return curves_figure(panels, png_path, ncols=len(panels), panel_size=(900, 650))


def _parameters_rows(name, calibration):
    """(parameter, ours cm, paper cm) rows."""
    ours = dict(zip(calibration.parameter_names, 100 * np.asarray(calibration.parameters)))
    paper = PAPER[name]["parameters_cm"]
    if name == "angels-2":
        radius = [v for k, v in ours.items() if k.startswith("a")]
        return [["a (cm)", radius[0] if radius else None, paper["a"]], ["L (cm, fixed)", 100 * 0.2, paper["L"]]]
    keys = {"a_e": ("a_1", "a_1=a_4"), "a_i": ("a_2", "a_2=a_3"), "L_e": ("L_12", "L_12=L_34"), "L_i": ("L_23",)}
    rows = []
    for label, candidates in keys.items():
        value = next((ours[c] for c in candidates if c in ours), None)
        rows.append([f"{label} (cm)", value, paper[label]])
    rows.append(["Gamma (17)", calibration.gamma_criterion, PAPER[name]["gamma"]])
    return rows


def reproduce(sensor_name, log_path, bem_poses, edge_length_m, folder, say=print):
    """One sensor: calibration, validation (PSM at every pose, BEM on a subset), figures; a summary dict."""
    from electrosense.meshes.sensor import preset
    from electrosense.validation.bench.log import read_bench_log
    from electrosense.validation.comparison.validate import validate_log
    from electrosense.validation.simulation.models import EvaluatorCache

    sensor = preset(sensor_name)
    t0 = time.perf_counter()
    reference, calibration = calibrate_like_the_paper(sensor, edge_length_m)
    say(f"{sensor_name}: free-space BEM and PSM calibration in {time.perf_counter() - t0:.1f} s, "
        f"Gamma = {calibration.gamma_criterion:.3e}")
    psm = calibration.model
    log = read_bench_log(log_path)
    if log.sensor.name != sensor_name:
        raise ValueError(f"{log_path}: the log's sensor is {log.sensor.name}, expected {sensor_name}")
    options = {} if edge_length_m is None else {"edge_length_m": edge_length_m}
    cache = EvaluatorCache(psm_model=psm, **options)
    full = validate_log(log, ("psm",), conductivity_correction=True, evaluators=cache, label=f"{sensor_name} (PSM, all poses)")
    rows = _bem_subset(log, bem_poses)
    sub = validate_log(_subset_log(log, rows), ("bem", "psm"), conductivity_correction=True, evaluators=cache,
                       progress=True, label=f"{sensor_name} (BEM and PSM, {len(rows)} poses)", **options)
    psm_vs_bem = sub.model_difference.overall["mean_abs"]
    fit = full.corrections["psm"]
    summary = {
        "sensor": sensor_name,
        "log": Path(log_path).name,
        "n_poses": len(log),
        "n_bem_poses": int(len(rows)),
        "psm_vs_bem_mean": psm_vs_bem,
        "bench_vs_psm_mean": full.comparisons["psm"].overall["mean_abs"],
        "bench_vs_bem_mean": sub.comparisons["bem"].overall["mean_abs"],
        "correction_psm": fit.scale - 1.0,
        "correction_psm_std": fit.std_error,
        "correction_bem": sub.corrections["bem"].scale - 1.0,
        "correction_bem_std": sub.corrections["bem"].std_error,
        "after_correction_psm_mean": full.corrected["psm"].overall["mean_abs"],
        "after_correction_bem_mean": sub.corrected["bem"].overall["mean_abs"],
        "parameters": _parameters_rows(sensor_name, calibration),
        "bem_seconds": sub.seconds.get("bem"),
    }
    U = log.U_V[:, None]
    x = log.poses[:, 0]
    png = paper_axes_figure(sensor_name, x, U / full.model_currents_A["psm"], x[rows],
                            U[rows] / sub.model_currents_A["bem"], x, log.resistance_ohm,
                            U / fit.corrected_bench(log.currents_A), sensor.receivers,
                            Path(folder) / f"paper_axes_{sensor_name}.png")
    return summary, [full, sub], png


def _table_rows(summaries):
    rows = []
    for s in summaries:
        p = PAPER[s["sensor"]]
        rows += [
            [s["sensor"], "PSM vs BEM, mean relative error (%)", 100 * s["psm_vs_bem_mean"], 100 * p["psm_vs_bem"]],
            [s["sensor"], "bench vs PSM before correction (%)", 100 * s["bench_vs_psm_mean"], 100 * p["bench_vs_psm"]],
            [s["sensor"], "bench vs BEM before correction (%)", 100 * s["bench_vs_bem_mean"], None],
            [s["sensor"], "conductivity correction, PSM (%)", 100 * s["correction_psm"], 100 * p["correction"]],
            [s["sensor"], "  its std. error (%)", 100 * s["correction_psm_std"], None],
            [s["sensor"], "conductivity correction, BEM (%)", 100 * s["correction_bem"], None],
            [s["sensor"], "bench vs PSM after correction (%)", 100 * s["after_correction_psm_mean"], None],
            [s["sensor"], "bench vs BEM after correction (%)", 100 * s["after_correction_bem_mean"], None],
        ]
        rows += [[s["sensor"], f"PSM parameter {r[0]}", r[1], r[2]] for r in s["parameters"]]
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sensors", default="angels-2,angels-4", help="comma-separated presets (angels-2, angels-4)")
    ap.add_argument("--logs", type=Path, default=None,
                    help="folder with <sensor>_wall-to-wall.csv virtual-bench logs (default: the bundled data)")
    ap.add_argument("--bench-model", choices=("bundled", "bem"), default="bundled",
                    help="bundled: the shipped virtual-bench logs (PSM physics); bem: make logs here with the BEM")
    ap.add_argument("--bem-poses", type=int, default=41, help="poses at which the BEM is run (spread along the path)")
    ap.add_argument("--edge-length", type=float, default=None, help="BEM sensor edge length (m); default: the mesher's")
    ap.add_argument("--quick", action="store_true", help="coarse BEM mesh (12 mm) and 9 BEM poses")
    ap.add_argument("--out", type=Path, default=Path("paper-reproduction"), help="report folder")
    args = ap.parse_args(argv)
    from electrosense.meshes.render import offscreen_backend

    offscreen_backend()  # EGL or OSMesa for the 3D pictures, chosen once
    if args.quick:
        args.bem_poses = min(args.bem_poses, 9)
        args.edge_length = args.edge_length or 0.012

    from electrosense.validation.comparison.report import write_validation_report
    from electrosense.validation.report.html import Figure, Section, Table

    data = args.logs or Path(__file__).resolve().parent.parent / "data"
    args.out.mkdir(parents=True, exist_ok=True)
    summaries, results, figures = [], [], []
    t0 = time.perf_counter()
    for name in [s.strip() for s in args.sensors.split(",") if s.strip()]:
        if name not in PAPER:
            raise SystemExit(f"unknown sensor {name!r}: the paper has angels-2 and angels-4")
        if args.bench_model == "bem":
            from electrosense.meshes.sensor import preset

            log_path = make_bem_bench_log(preset(name), args.out / f"{name}_wall-to-wall_bem-bench.csv",
                                          n=max(args.bem_poses, 9), edge_length_m=args.edge_length)
        else:
            log_path = data / f"{name}_wall-to-wall.csv"
            if not log_path.exists():
                raise SystemExit(f"no virtual-bench log {log_path}")
        summary, res, png = reproduce(name, log_path, args.bem_poses, args.edge_length, args.out)
        summaries.append(summary)
        results += res
        figures.append(Figure(png, f"{name}: ours on the paper's axes ({PAPER[name]['figure']}): PSM solid, BEM "
                                   "dashed, virtual bench dots, bench after the conductivity correction squares; "
                                   "receivers 1, 2, 3 blue, red, green as in the paper."))
    rows = _table_rows(summaries)
    print()
    print(f"{'sensor':<10} {'quantity':<44} {'ours':>12} {'paper':>10}")
    for sensor, what, ours, paper in rows:
        o = "-" if ours is None else f"{ours:12.4g}"
        p = "-" if paper is None else f"{paper:10.4g}"
        print(f"{sensor:<10} {what:<44} {o:>12} {p:>10}")
    print(f"({time.perf_counter() - t0:.0f} s)")
    source = ("bundled virtual-bench logs (PSM physics with the paper's conductivity offset and the bench's noise)"
              if args.bench_model == "bundled" else "virtual-bench logs made here with the BEM as the physics")
    section = Section(
        "Paper comparison",
        ["Our figures beside the paper's (Jawad et al.): angels-2 and angels-4 moved wall to wall at y = 0 in the "
         f"1 m tank, 0.0354 S/m. Bench data: {source}; so 'bench vs model' and the correction measure what the "
         "virtual bench injected, while 'PSM vs BEM' is a genuine reproduction of the paper's model comparison.",
         "The paper's plots are not shipped with electrosense; ours are drawn on the paper's axes and with its line "
         "conventions, so that they can be laid beside the printed figures."],
        tables=[Table(["sensor", "quantity", "ours", "paper"], rows, caption="Ours beside the paper", digits=4)],
        figures=figures, side_by_side=False)
    paths = write_validation_report(results, args.out, title="electrosense: the paper's comparisons reproduced",
                                    leading_sections=[section], potential=False,
                                    extra_metrics={"paper_reproduction": {"ours": summaries, "paper": PAPER}})
    print(f"report: {paths['index']}")
    return summaries


if __name__ == "__main__":
    main()
