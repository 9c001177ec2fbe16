"""``esense demo``: the whole chain on the bundled bench logs, into one report.

Example::

    esense demo -o esense-demo
    esense demo --quick -o demo-quick     # reduced settings (coarse meshes, few poses)

Steps: mesh the paper's sensors (those named by the bundled logs), compute
their free-space BEM conductance matrices, calibrate the PSM on them, validate
BEM and PSM against the bundled example logs (with the paper's conductivity
correction), run the gap diagnosis when it is installed, and write one report
(``index.html``, ``metrics.json``, PNGs, the calibrated PSMs as JSON). The
folder's ``index.html`` is printed at the end.
"""
from __future__ import annotations

import io
import time
from pathlib import Path

import click

#: The paper's free-space S_BEM of the 4-electrode sensor, in units of gamma/100 (S per S/m), emitter 4.
PAPER_S_BEM_ANGELS4 = [[7.1970, -2.7412, -2.2540], [-2.7412, 7.6781, -2.6875], [-2.2540, -2.6875, 7.6781]]

#: Reduced and full settings: BEM sensor mesh edge length (m), BEM poses per log, potential figure grid
#: (0: none; drawn for the first log of each sensor), how many logs. The full demo is sized to run in under 5 minutes
#: on 2 cores: the BEM solves pose by pose, so it sees a subset of each log. The diagnosis corrects its PSM baseline by
#: the BEM on about ``diagnosis_bem_poses`` poses per log (dense near the walls), so that the PSM's own approximation
#: is not taken for physics.
SETTINGS = {
    "full": {"edge_length_m": 0.008, "bem_poses": 13, "potential_n": 61, "max_logs": None, "diagnosis_bem_poses": 40},
    "quick": {"edge_length_m": 0.012, "bem_poses": 3, "potential_n": 0, "max_logs": 1, "diagnosis_bem_poses": 8},
}


def bundled_logs() -> list[Path]:
    """The example bench logs shipped with the package (validation/data/*.csv)."""
    folder = Path(__file__).resolve().parent.parent / "data"
    return sorted(folder.glob("*.csv"))


def _sensor_section(sensor, folder: Path, edge_length_m, bar, echo):
    """Mesh, free-space BEM and PSM calibration of one sensor: (Section, PSM model)."""
    import numpy as np

    from electrosense.meshes.quality import mesh_quality
    from electrosense.meshes.render import RenderUnavailable, render_mesh
    from electrosense.meshes.sensor_mesh import mesh_sensor
    from electrosense.psm import calibrate
    from electrosense.validation.report.html import Figure, Section, Table
    from electrosense.validation.simulation.models import free_space_bem

    name = sensor.name
    mesh = mesh_sensor(sensor, edge_length_m=edge_length_m)
    try:
        figures = [Figure(render_mesh(mesh, folder / f"mesh_{name}.png", emitter=sensor.emitter,
                                      title=f"{name}: BEM mesh ({mesh.n_triangles} triangles)"),
                          f"{name}: BEM mesh, electrodes coloured, the emitter named in the legend")]
        notes = []
    except RenderUnavailable as exc:
        figures, notes = [], [f"mesh picture left out: {exc}"]
    quality = mesh_quality(mesh)
    bar.update(1)
    t0 = time.perf_counter()
    reference = free_space_bem(sensor, edge_length_m)
    bem_s = time.perf_counter() - t0
    bar.update(1)
    t0 = time.perf_counter()
    # the paper's fit: mirror-symmetric spheres; with 2 electrodes the model length is the real one (20 cm)
    calibration = calibrate(reference, symmetric=True, sensor=sensor,
                            fix_length_m=sensor.length_m if sensor.n_electrodes == 2 else None)
    psm_s = time.perf_counter() - t0
    model = calibration.model
    model.save(folder / f"psm_{name}.json")
    bar.update(1)
    echo(f"{name}: {mesh.n_triangles} triangles, free-space BEM {bem_s:.1f} s, PSM fit Gamma = "
         f"{calibration.gamma_criterion:.2e} ({psm_s:.1f} s)")
    S = 100 * reference.S_S  # gamma/100 units: S per (S/m) x 100
    tables = [Table(["", *[f"receiver {k}" for k in reference.receivers]],
                    [[f"receiver {k}", *row] for k, row in zip(reference.receivers, S.tolist())],
                    caption=f"{name}: free-space BEM S in units of sigma/100 (S per S/m, x100)", digits=5)]
    if name == "angels-4":
        paper = np.array(PAPER_S_BEM_ANGELS4)
        rel = (S - paper) / np.abs(paper)
        tables.append(Table(["", *[f"receiver {k}" for k in reference.receivers]],
                            [[f"receiver {k}", *(100 * row).tolist()] for k, row in zip(reference.receivers, rel)],
                            caption="angels-4: our S against the paper's S_BEM table, relative difference (%)",
                            digits=3))
    tables.append(Table(
        ["parameter", "value (cm)", "uncertainty (cm)"],
        [[n, 100 * v, 100 * u] for n, v, u in zip(calibration.parameter_names, np.asarray(calibration.parameters),
                                                   np.asarray(calibration.uncertainties))],
        caption=f"{name}: PSM calibrated on the free-space BEM, criterion (17) Gamma = "
                f"{calibration.gamma_criterion:.3e}", digits=4))
    text = [f"Mesh: {mesh.n_triangles} triangles ({_quality_text(quality)}). Free-space BEM conductance in "
            f"{bem_s:.1f} s; PSM fit in {psm_s:.1f} s, saved as psm_{name}.json."]
    return Section(f"Sensor {name}", text, tables=tables, figures=figures, notes=notes), model


def _quality_text(q) -> str:
    return (f"smallest angle {q.min_angle_deg:.1f} deg, largest aspect ratio {q.max_aspect_ratio:.1f}, "
            f"edges {1000 * q.min_edge_m:.2f} to {1000 * q.max_edge_m:.2f} mm, "
            f"{'watertight' if q.is_watertight else 'NOT watertight'}")




def _format_params(params: dict, uncertainty: dict | None) -> str:
    uncertainty = uncertainty or {}
    parts = []
    for k, v in (params or {}).items():
        u = uncertainty.get(k)
        if isinstance(v, (int, float)):
            parts.append(f"{k} = {v:.4g}" + (f" +- {u:.2g}" if isinstance(u, (int, float)) else ""))
        else:
            parts.append(f"{k} = {v}")
    return "; ".join(parts)


class _Indented(io.TextIOBase):
    """A text stream that hands each complete line to ``echo`` with a prefix (a command's steps inside a bar).

    ``echo(line, file=...)`` is called with the standard output of the moment the stream was made, so that
    it can stand in for ``sys.stdout`` (``contextlib.redirect_stdout``) without writing to itself.
    """

    def __init__(self, echo, prefix: str):
        import sys

        self.echo, self.prefix, self._part, self._out = echo, prefix, "", sys.stdout

    def writable(self) -> bool:
        return True

    def write(self, text: str) -> int:
        *lines, self._part = (self._part + text).split("\n")
        for line in lines:
            if line.strip():
                self.echo(self.prefix + line, file=self._out)
        return len(text)


def _diagnosis_section(logs, log_paths, folder: Path, echo, bar=None, bem_poses: int = 0, edge_length_m=None):
    """The gap diagnosis of each log into folder/diagnosis/<log>; a summary Section with its figures.

    The demo takes the fast path: the PSM calibrated by the demo (``psm_<sensor>.json``), corrected by the BEM on
    about ``bem_poses`` poses per log (``esense diagnose --model psm --bem-correction N``; 0: the bare PSM) with the
    demo's mesh edge length. ``esense diagnose LOG`` without options takes the BEM-anchored baseline, whose own
    error is known before any effect is named (minutes per log on a new sensor).
    """
    import contextlib

    from electrosense.validation.diagnosis.observations import from_bench_logs
    from electrosense.validation.diagnosis.pipeline import diagnose
    from electrosense.validation.diagnosis.report import diagnosis_dict, write_report
    from electrosense.validation.report.html import Figure, Section, Table

    sections = []
    for log, path in zip(logs, log_paths):
        stem = Path(path).stem
        sub = folder / "diagnosis" / stem
        psm_file = folder / f"psm_{log.sensor.name}.json"
        options = {"edge_length_m": edge_length_m} if (bem_poses and edge_length_m) else {}
        echo(f"diagnosis of {Path(path).name}: fitting the candidate effects"
             + (f" on a PSM corrected by the BEM at ~{bem_poses} poses" if bem_poses else "") + " ...")
        chatter = _Indented(echo, f"  {stem}: ")  # the diagnosis's own steps, shown as they come (minutes of work)
        try:
            with contextlib.redirect_stdout(chatter):
                result = diagnose(from_bench_logs([log]), model="psm", model_options=options,
                                  psm_model=psm_file if psm_file.exists() else None, bem_correction_poses=bem_poses,
                                  progress=lambda step: print(step))
                write_report(result, sub)
            d = diagnosis_dict(result)
        except Exception as exc:  # the report still stands without it; say why
            sections.append(Section(stem, notes=[f"diagnosis failed: {type(exc).__name__}: {exc}"]))
            continue
        finally:
            if bar is not None:
                bar.update(1)
        rows = [[c.get("effect"), _format_params(c.get("params"), c.get("uncertainty")),
                 100 * c["heldout_gap"] if isinstance(c.get("heldout_gap"), (int, float)) else None,
                 100 * c["shrink"] if isinstance(c.get("shrink"), (int, float)) else None]
                for c in d.get("ranking", [])[:8]]
        chosen = ", ".join(d.get("chosen", [])) or "none"
        before, after = d.get("gap_before"), d.get("gap_after")
        gap_text = (f"{100 * before:.3f} % -> {100 * after:.3f} %" if isinstance(before, (int, float))
                    and isinstance(after, (int, float)) else f"{before} -> {after}")
        echo(f"diagnosis of {Path(path).name}: {chosen} (held-out RMS gap {gap_text})")
        text = [f"Chosen effect(s): {chosen}. Held-out RMS relative gap: {gap_text}."]
        if "source" in log.meta:
            text.append(f"What the log's meta says about how it was made: {log.meta['source']}")
        notes = [f"cannot tell apart {' / '.join(c['pair'])}: {c.get('separate_by', c.get('reason', ''))}"
                 for c in (d.get("confusable") or [])[:4] if isinstance(c, dict) and "pair" in c]
        figures = [Figure(sub / name, f"{stem}: {caption}") for name, caption in
                   (("gap_by_place.png", "where the gap lies"), ("ranking.png", "candidate effects, held-out"))
                   if (sub / name).exists()]
        sections.append(Section(
            stem, text, notes=notes, figures=figures, side_by_side=True,
            tables=[Table(["effect", "parameters +- std. error", "held-out gap (%)", "shrink (%)"], rows,
                          caption="Candidate effects, best first")] if rows else [],
            links=[("the full diagnosis of this log", f"diagnosis/{stem}/index.html")]))
    intro = ("Which unmodelled effect explains the gap between the bench and the PSM: each candidate fitted on part of "
             "the data and scored on the rest (esense diagnose --model psm).")
    if bem_poses:
        intro += (f" The PSM baseline is corrected by the BEM on about {bem_poses} poses per log (esense diagnose "
                  "--model psm --bem-correction), so that the PSM's own approximation near the walls is not taken for "
                  "physics. Without options, esense diagnose takes the BEM-anchored baseline, slower and with a "
                  "known error budget.")
    return Section("Gap diagnosis", [intro],
                   subsections=sections)


@click.command("demo")
@click.option("-o", "--out", "outdir", type=click.Path(file_okay=False, path_type=Path), default=Path("esense-demo"),
              show_default=True, help="Folder of the report (index.html, metrics.json, PNGs, PSM JSON files).")
@click.option("--quick", is_flag=True,
              help="Reduced settings for a smoke test: coarse BEM mesh, one log, 3 BEM poses, no potential figure.")
@click.option("--bem-poses", type=click.IntRange(min=2), default=None,
              help="About how many poses per log the BEM (and the comparison) uses; the PSM's figures use the same.")
@click.option("--data", "data_dir", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="Use the bench logs (*.csv) of this folder instead of the bundled ones.")
@click.option("--no-diagnosis", is_flag=True, help="Skip the gap diagnosis.")
@click.option("--quiet", is_flag=True, help="No progress bars.")
def demo(outdir, quick, bem_poses, data_dir, no_diagnosis, quiet):
    """Mesh the paper's sensors, compute BEM matrices, calibrate the PSM, validate both on the bundled logs, report."""
    from tqdm.auto import tqdm

    from electrosense.meshes.render import offscreen_backend
    from electrosense.validation.bench.log import read_bench_log
    from electrosense.validation.cli.validate_cmd import print_summary, validate_logs
    from electrosense.validation.comparison.report import write_validation_report

    t_start = time.perf_counter()
    settings = dict(SETTINGS["quick" if quick else "full"])
    if bem_poses is not None:
        settings["bem_poses"] = bem_poses
    paths = bundled_logs() if data_dir is None else sorted(Path(data_dir).glob("*.csv"))
    if not paths:
        raise click.ClickException(f"no bench logs (*.csv) in {data_dir or 'the bundled data (validation/data)'}")
    if settings["max_logs"]:
        paths = paths[: settings["max_logs"]]
    logs = [read_bench_log(p) for p in paths]
    sensors = list({log.sensor.name: log.sensor for log in logs}.values())
    outdir.mkdir(parents=True, exist_ok=True)
    echo = click.echo
    if offscreen_backend() is None:  # EGL or OSMesa, chosen once for every picture
        echo("note: no offscreen OpenGL (EGL or OSMesa) here: the report leaves out its 3D pictures")
    echo(f"esense demo: {len(logs)} bundled log(s) ({', '.join(p.name for p in paths)}), "
         f"sensors {', '.join(s.name for s in sensors)}; report in {outdir}")
    steps = 3 * len(sensors) + 3 * len(logs) + (0 if no_diagnosis else len(logs))
    with tqdm(total=steps, desc="demo", unit="step", disable=quiet) as bar:
        bar.set_description("sensors: mesh, BEM, PSM")
        sensor_sections, psms = [], {}
        for sensor in sensors:
            section, psms[sensor.name] = _sensor_section(sensor, outdir, settings["edge_length_m"], bar, bar.write)
            sensor_sections.append(section)
        bar.set_description("validate (BEM, PSM)")
        strides = [max(1, len(log) // max(settings["bem_poses"] - 1, 1)) for log in logs]
        results = []
        for log, stride in zip(logs, strides):
            results += validate_logs([log], ("bem", "psm"), psm=psms, conductivity_correction=True, stride=stride,
                                     edge_length_m=settings["edge_length_m"], show_progress=not quiet, bar=bar)
            results[-1].label = _unique(results[-1].label, results[:-1])
        extra = []
        if not no_diagnosis:
            bar.set_description("gap diagnosis")
            extra.append(_diagnosis_section(logs, paths, outdir, bar.write, bar,
                                            bem_poses=settings["diagnosis_bem_poses"],
                                            edge_length_m=settings["edge_length_m"]))
        bar.set_description("figures and report")
        intro = [
            "This report is made by `esense demo` from the example bench logs bundled with electrosense: "
            "the paper's sensors are meshed, their free-space BEM conductance matrices computed, the "
            "poly-spherical model (PSM) calibrated on them, and both models compared with the logged currents.",
            f"Settings: {'quick (reduced)' if quick else 'full'}; BEM mesh edge length "
            f"{settings['edge_length_m'] or 'mesher default'} m; the BEM solves pose by pose, so the comparison "
            "uses " + ", ".join(f"{len(r.log)} poses of {p.name} (every {s}th)" if s > 1 else f"all poses of {p.name}"
                                for r, p, s in zip(results, paths, strides)) + ".",
        ]
        report = write_validation_report(
            results, outdir, title="electrosense demo: BEM and PSM against the bench",
            leading_sections=sensor_sections, extra_sections=extra, intro=intro,
            footer=f"esense demo{' --quick' if quick else ''}; {time.perf_counter() - t_start:.0f} s",
            potential=settings["potential_n"] > 0, potential_n=settings["potential_n"] or 81,
            potential_logs=list({r.log.sensor.name: r.label for r in reversed(results)}.values()),
            edge_length_m=settings["edge_length_m"], progress=bar,
            extra_metrics={"demo": {"settings": settings, "logs": [p.name for p in paths],
                                    "psm_files": [f"psm_{s.name}.json" for s in sensors]}})
    print_summary(results, report)
    echo(f"done in {time.perf_counter() - t_start:.0f} s; open {report['index'].resolve()}")


def _unique(label, earlier) -> str:
    used = {r.label for r in earlier}
    out, k = label, 2
    while out in used:
        out, k = f"{label}-{k}", k + 1
    return out
