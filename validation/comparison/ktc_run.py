"""The KTC study's run: floors, the fit, the predictions, the diagnosis, and the metrics (``metrics.json``).

:func:`run_ktc` is what ``esense study ktc`` does; the metrics' keys:

* ``linear_floor_rel``: each file's linear floor (``folder/file``), and of each tank's change;
* ``ref_rms_rel``: the empty tank of the fit folder on held-out patterns, beside its floor;
* ``fitted``: every unknown with its standard error (``null``: not determined), the derived conductivity and
  contact impedances for a current unit of 1 mA, ``not_separable`` and ``correlated``;
* ``fit_tanks``: the fit folder's tanks, fitted (with their drift) and held out by tank (the drift from
  :func:`~electrosense.validation.comparison.ktc.water_change`, and ``..._reference_water`` without it);
* ``predicted``: per predicted file ``difference_rms_rel`` (the water's change since the reference taken from the
  file, cross-fitted by pattern), ``difference_rms_rel_reference_water`` (without it), ``water_change_rel`` and
  its standard error, ``difference_floor_rel``, ``total_rms_rel``;
* ``diagnosis``: where the gap lies and what each effect explains
  (:mod:`electrosense.validation.diagnosis.ktc_gap`).
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from electrosense.validation.comparison.ktc import file_floors, fit_ktc, predict_folder, rms_rel

__all__ = ["run_ktc", "folder_labels", "fitted_table"]


def folder_labels(folders) -> list[str]:
    """A unique label per folder (its name, numbered where two share one)."""
    out, seen = [], {}
    for f in folders:
        base = Path(f.path).name or "folder"
        seen[base] = seen.get(base, 0) + 1
        out.append(base if seen[base] == 1 else f"{base}#{seen[base]}")
    return out


def fitted_table(fit) -> dict:
    """{unknown: {value, se, unit, meaning}} of every unknown that was fitted, and the derived physical values."""
    se = dict(zip(fit.ref_fit.names, fit.ref_fit.se))
    if fit.object_fit is not None:
        se.update({n: v for n, v in zip(fit.object_fit.names, fit.object_fit.se) if n not in fit.problem.fixed})
    unknowns = {u.name: u for u in fit.problem.unknowns}
    out = {}
    for n, v in fit.values.items():
        s = se.get(n, float("nan"))
        out[n] = {"value": v, "se": None if not np.isfinite(s) else float(s), "unit": unknowns[n].unit,
                  "meaning": unknowns[n].meaning}
    sc = fit.scale
    sig = 1e-3 / sc
    s_se = out["log_scale"]["se"]
    zeta = fit.zeta()
    out["derived"] = {
        "conductivity_S_per_m_if_mA": {"value": sig, "se": None if s_se is None else sig * s_se,
                                       "note": "the current's unit and the conductivity only appear as a ratio; "
                                               "this is the conductivity were the file's currents in mA"},
        "contact_impedance_ohm_m2_if_mA": [float(z / sig) for z in zeta],
        "electrode_height_m": fit.values["height_frac"] * fit.values["depth_m"],
        "metal_contact_impedance_ohm_m2_if_mA": float(math.exp(fit.values["log_zeta_metal"]) / sig),
    }
    return out


def run_ktc(fit_folder, predict_folders, out_dir: Path, n_modes: int = 30, figures: bool = True,
            diagnosis: bool = True, progress=print) -> dict:
    """Fit, predict, diagnose; write the report and figures in ``out_dir``; return the metrics."""
    t0 = time.perf_counter()
    labels = folder_labels([fit_folder, *predict_folders])
    floors = {labels[0]: file_floors(fit_folder)}
    for lab, f in zip(labels[1:], predict_folders):
        floors[lab] = file_floors(f)
    notes = [f"{lab}: {n}" for lab, f in zip(labels, [fit_folder, *predict_folders]) for n in f.notes]
    fit = fit_ktc(fit_folder, n_modes=n_modes, progress=progress)
    t1 = time.perf_counter()
    ref_floor = floors[labels[0]]["ref.mat"]["floor_rms_rel"]
    metrics: dict = {
        "linear_floor_rel": {f"{lab}/{k}": v["floor_rms_rel"] for lab, fl in floors.items() for k, v in fl.items()},
        "linear_floor_noise_rel": {f"{lab}/{k}": v["noise_rms_rel"] for lab, fl in floors.items()
                                   for k, v in fl.items()},
        "ref_rms_rel": fit.scores["ref_rms_rel"],
        "ref_linear_floor_rel": ref_floor,
        "ref_rms_over_floor": fit.scores["ref_rms_rel"] / ref_floor,
        "ref_train_rms_rel": fit.scores["ref_train_rms_rel"],
        "fitted": fitted_table(fit),
        "not_separable": {"empty_tank": fit.ref_fit.not_separable,
                          "tanks": [] if fit.object_fit is None else fit.object_fit.not_separable},
        "correlated": {"empty_tank": fit.ref_fit.correlated,
                       "tanks": [] if fit.object_fit is None else fit.object_fit.correlated},
        "at_bound": sorted(set(fit.ref_fit.at_bound) | set([] if fit.object_fit is None else fit.object_fit.at_bound)),
        "noise_model": "independent errors of one deviation per file: its linear floor's per-voltage noise",
        "fit_folder": labels[0], "notes": notes,
        "model": {"n_modes": n_modes, "modal_solves": None},
        "evaluations": {"empty_tank": fit.ref_fit.nfev, "tanks": None if fit.object_fit is None else fit.object_fit.nfev},
    }
    fit_tanks = {}
    if fit.object_fit is not None:
        pred_fit = fit.problem.predictions(fit.x)
        for b, p in zip(fit.problem.blocks, pred_fit):
            meas = np.where(b.mask, b.measured, np.nan)
            held = fit.heldout["tanks"][b.tank]
            fit_tanks[b.tank] = {"fitted_rms_rel": rms_rel(np.where(b.mask, p, np.nan) - meas, meas),
                                 "heldout_rms_rel": rms_rel(held["water"], meas),
                                 "heldout_rms_rel_reference_water": rms_rel(held["reference_water"], meas),
                                 "drift": fit.values[f"drift_{b.tank}"],
                                 "difference_floor_rel": floors[labels[0]][f"{b.tank}.mat (change)"]["floor_rms_rel"]}
    metrics["fit_tanks"] = fit_tanks
    predictions = {}
    for lab, f in zip(labels[1:], predict_folders):
        try:
            res = predict_folder(fit, f, lab, progress=progress)
        except ValueError as exc:                   # another layout than the fit's: said, the rest goes on
            res = {name: {"error": str(exc)} for name in f.tanks} or {"(folder)": {"error": str(exc)}}
        for name, r in res.items():
            predictions[f"{lab}/{name}"] = r
    metrics["predicted"] = {k: (r["metrics"] if "metrics" in r else {"error": r["error"]})
                            for k, r in predictions.items()}
    scored = [r["metrics"] for r in predictions.values() if "metrics" in r]
    if scored:
        vals = [m["difference_rms_rel"] for m in scored]
        strict = [m["difference_rms_rel_reference_water"] for m in scored]
        metrics["predicted_summary"] = {"difference_rms_rel_median": float(np.median(vals)),
                                        "difference_rms_rel_max": float(np.max(vals)), "files": len(vals),
                                        "reference_water_median": float(np.median(strict)),
                                        "reference_water_max": float(np.max(strict))}
    t2 = time.perf_counter()
    diag = None
    if diagnosis:
        from electrosense.validation.diagnosis.ktc_gap import diagnose_ktc

        progress("diagnosis: where the gap lies and what explains it")
        diag = diagnose_ktc(fit, fit_folder, predictions, progress=progress)
        metrics["diagnosis"] = diag["metrics"]
    t3 = time.perf_counter()
    metrics["model"]["modal_solves"] = fit.forward.solves
    metrics["seconds"] = {"fit_s": t1 - t0, **{k: v for k, v in fit.seconds.items()}, "predict_s": t2 - t1,
                          "diagnosis_s": t3 - t2}
    from electrosense.validation.comparison.ktc_report import write_ktc_report

    write_ktc_report(out_dir, metrics, fit, fit_folder, predictions, diag, figures=figures, progress=progress)
    metrics["seconds"]["report_s"] = time.perf_counter() - t3
    return metrics
