"""``esense validate`` / ``esense diagnose`` on transfer logs: compare each with the BEM of its scene, diagnose, report.

The log's meta names its scene (relative to the log's folder); the scene's
``[protocol]`` table says which set-up is the reference and where the balls are.
``validate`` runs the comparison (:mod:`electrosense.validation.comparison.transfer`: noise
floor, empty tank held out, balls); ``diagnose`` adds the diagnosis candidates
(:mod:`electrosense.validation.diagnosis.transfer`: electrode positions, water depth,
channel gains...). Figures and report: :mod:`electrosense.validation.comparison.transfer_report`.
"""
from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

__all__ = ["all_transfer_logs", "run_transfer_comparison", "run_transfer_logs"]


def all_transfer_logs(paths) -> bool:
    """True when every path is a transfer log (and there is at least one)."""
    from electrosense.validation.bench.transfer.log import is_transfer_log

    paths = list(paths)
    return bool(paths) and all(is_transfer_log(p) for p in paths)


def run_transfer_comparison(data, scene_path, out, diagnose: bool = True, scene_fit: bool = False,
                            fit_setup: str | None = None) -> dict:
    """Compare a transfer log (or an EIT phantom's .mat) with the BEM of ``scene_path``; write everything to ``out``.

    Writes ``out/metrics.json``, the figures and ``report.md`` (and, from a
    .mat, ``out/transfer_log.csv`` beside a copy of the scene file); returns
    the metrics. ``diagnose``: also run the diagnosis candidates. ``scene_fit``: also fit the scene's and the
    instrument's unknowns on the BEM across set-ups (on ``fit_setup`` and the reference; scored on the other
    set-ups; :mod:`electrosense.validation.diagnosis.tank_scene_fit`), written as ``metrics["scene_fit"]``.
    Raises :class:`electrosense.validation.comparison.transfer.TransferMismatchError` when the
    log and the scene disagree (signs, set-ups).
    """
    from electrosense.meshes.scene_file import load_scene, load_scene_settings
    from electrosense.validation.bench.transfer.eit_mat import eit_mat_to_transfer_log
    from electrosense.validation.bench.transfer.log import read_transfer_log
    from electrosense.validation.comparison.study_mesh import study_bem_options
    from electrosense.validation.comparison.transfer import (
        compare_transfer_log,
        measurement_noise,
        model_transfer_ohm,
        setup_table,
    )
    from electrosense.validation.comparison.transfer_report import goals, write_transfer_report

    t_start, cpu_start = time.perf_counter(), time.process_time()
    data, scene_path, out = Path(data), Path(scene_path), Path(out)
    out.mkdir(parents=True, exist_ok=True)
    scene_copy = out / scene_path.name
    if scene_copy.resolve() != scene_path.resolve():
        shutil.copyfile(scene_path, scene_copy)
    scene = load_scene(scene_path)
    settings = load_scene_settings(scene_path)
    protocol = settings.get("protocol", {})
    log_path = (eit_mat_to_transfer_log(data, out / "transfer_log.csv", scene=scene_path.name,
                                        ring=protocol.get("ring"))
                if data.suffix.lower() == ".mat" else data)
    log = read_transfer_log(log_path)
    sigma = float(settings.get("water", {}).get("sigma_S_per_m", 1.0))
    if scene_fit:        # a misspelt tolerance refused before any solve
        from electrosense.validation.diagnosis.tank_scene_fit import checked_tolerance

        try:
            checked_tolerance(settings.get("tolerance"))
        except ValueError as exc:
            raise ValueError(f"{scene_path}: {exc}") from None
    table = setup_table(log, str(protocol.get("reference", log.setups[0])))
    bem_options, mesh, empty = study_bem_options(
        scene, sigma, dict(settings.get("bem", {})), lambda K: model_transfer_ohm(K, table.drive, table.measure),
        measurement_noise(table.drive, table.measure, table.Z_ohm, protocol.get("ring", []))["fit_noise_rel"])
    comp = compare_transfer_log(log, scene, sigma, bem_options, protocol, solution=empty)
    comp.metrics["bem"]["mesh"] = mesh
    metrics: dict = {"data": data.name, "scene": scene_path.name, "setups": list(log.setups), **comp.metrics}
    resid = None
    if diagnose:
        from electrosense.validation.diagnosis.transfer import diagnose_transfer, one_geometry

        try:
            diagnosis, resid, shape, seconds = diagnose_transfer(comp, scene, sigma, bem_options, protocol)
        except (ValueError, MemoryError) as exc:     # the comparison is written all the same
            diagnosis, shape, seconds = {"error": f"the diagnosis stopped: {exc}"}, None, {}
        metrics["bem"].update(seconds)
        if shape is not None and comp.measured_signals:
            t0 = time.perf_counter()
            try:
                diagnosis["one_geometry"] = one_geometry(comp, shape, diagnosis["candidates"]["ring_radius"], sigma,
                                                         bem_options, protocol)
            except (ValueError, MemoryError) as exc:
                diagnosis["one_geometry"] = {"error": f"not computed: {exc}"}
            metrics["bem"]["shape_ball_solves_s"] = time.perf_counter() - t0
        metrics["diagnosis"] = diagnosis
    if scene_fit:
        from electrosense.validation.diagnosis.tank_scene_fit import fit_tank_scene

        try:
            metrics["scene_fit"] = fit_tank_scene(log, scene, sigma, bem_options, protocol, fit_setup,
                                                  tolerance=settings.get("tolerance"))
        except Exception as exc:     # an optional step: what was computed before is written all the same
            metrics["scene_fit"] = {"error": f"the scene fit stopped: {type(exc).__name__}: {exc}"}
    metrics["goals"] = goals(metrics)
    metrics["wall_s"] = time.perf_counter() - t_start
    metrics["cpu_s"] = time.process_time() - cpu_start
    (out / "metrics.json").write_text(json.dumps(metrics, indent=1))
    write_transfer_report(out, comp, metrics, resid)
    return metrics


def run_transfer_logs(paths, outdir, positions: bool = True) -> None:
    """Compare each transfer log with the BEM of its scene; one sub-folder of ``outdir`` per log.

    ``positions``: also run the diagnosis (electrode positions from one
    solve's sensitivities, water depth, channel gains...); False: the
    comparison only. Prints each log's headline numbers beside the goals.
    """
    from electrosense.validation.bench.transfer.log import read_transfer_log
    from electrosense.validation.comparison.transfer import TransferMismatchError
    from electrosense.validation.comparison.transfer_report import summary_text

    paths = list(paths)
    for p in paths:
        log = read_transfer_log(p)
        sub = Path(outdir) / Path(p).stem if len(paths) > 1 else Path(outdir)
        try:
            metrics = run_transfer_comparison(p, log.scene_path(), sub, diagnose=positions)
        except TransferMismatchError as exc:
            raise SystemExit(f"{p}: {exc}") from None
        print(summary_text(metrics))
