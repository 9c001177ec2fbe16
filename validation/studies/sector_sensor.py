"""Sector electrodes: every done-when figure of the sector sensor beside its goal (BEM, PSM, CRB).

The sensor is no preset: 18 cm long, radius 1.1 cm, a head cap, a ring in 4
sectors (2 mm gaps), a whole ring, a ring in 4 sectors (1.5 mm gaps) and the
tail cap, which emits. Printed, each beside its goal:

1. the all-sectors identity: the same sensor with no gaps, its sectors'
   rows and columns summed, against the whole sensor (each with its own
   default mesh and edge correction), per row of the row maximum;
2. equal currents: the spread of each ring's sector currents, the tail cap
   emitting, in unbounded water;
3. an independent code on the same mesh: bempp-cl (Galerkin P0,
   ``validation/studies/bempp_sensor.py``) against our collocation surface
   solution (both without edge correction), entry by entry of the row maximum;
4. the time of ``esense conductance --unbounded`` from an empty cache (wall
   and CPU), for this sensor (4-fold symmetric) and for one that no rotation
   maps onto itself (a ring in 4 sectors, one in 3: two mirror-image blocks);
5. refinement: the sector edges' spacing halved three times (the rings
   unchanged), the observed order of the surface K and the corrected default's
   distance from the Richardson limit; and the whole mesh refined (edge
   length x 1.4, 1, 1/1.4): how much the corrected K still moves;
6. the PSM against the BEM in the 1 m tank: passes along x, 3, 5, 7 and
   10 cm from the +y wall and from the -y wall, and a pass beside a
   conducting sphere on either side: the sector currents (mean relative
   error), the lateral signal left minus right of each split ring (RMS of
   the difference over the RMS of the BEM's signal), and its sign;
7. the Cramer-Rao bound on the lateral position y and the heading, with
   (x, y, yaw) unknown, from the PSM's Jacobian and the bench's noise
   (0.05 % of each receiver current, independent), for this sensor against
   the same sensor with whole rings, beside a wall.

Figures go to ``--out`` (default ``sector_sensor_study/``). Run:
``esense study sector_sensor [--quick] [--skip-bempp] [--skip-timing] [--out DIR]``
(about 20 minutes on 2 cores; ``--quick``: coarser meshes and fewer poses).
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from electrosense.meshes.sensor import Electrode, SensorDescription, save_sensor
from electrosense.validation.defaults import BENCH_CURRENT_NOISE_REL, NOMINAL_SIGMA_S_PER_M

SIGMA = NOMINAL_SIGMA_S_PER_M

STUDY_SENSOR = SensorDescription(
    "study-sectors", radius_m=0.011, length_m=0.18,
    electrodes=(Electrode("cap", 0.083, 0.09),
                Electrode("ring", 0.032, 0.038, sectors=4, sector_gap_m=0.002),
                Electrode("ring", -0.003, 0.003),
                Electrode("ring", -0.038, -0.031, sectors=4, sector_gap_m=0.0015),
                Electrode("cap", -0.09, -0.0825)),
    notes="sector study sensor (electrosense validation/studies/sector_sensor.py)")


def mirror_sensor() -> SensorDescription:
    """The study sensor with its second split ring in 3 sectors: no rotation maps it onto itself."""
    e = list(STUDY_SENSOR.electrodes)
    e[3] = Electrode("ring", -0.038, -0.031, sectors=3, sector_gap_m=0.0015)
    return SensorDescription("study-sectors-4-3", STUDY_SENSOR.radius_m, STUDY_SENSOR.length_m, tuple(e))


def gapless(sensor: SensorDescription) -> SensorDescription:
    from dataclasses import replace

    return replace(sensor, electrodes=tuple(replace(e, sector_gap_m=0.0) for e in sensor.electrodes))


def row_relative(A, B):
    """max |A - B| of each row over the row maximum of |B|."""
    return np.abs(A - B).max(axis=1) / np.abs(B).max(axis=1)


# ------------------------------------------------------------------------------------------------- 1, 2
def identity_and_equal_currents(edge_length_m):
    from electrosense.bem.solve import conductance_matrix
    from electrosense.meshes.scene import Scene

    s0 = gapless(STUDY_SENSOR)
    K0 = conductance_matrix(Scene(s0), SIGMA, edge_length_m=edge_length_m).K_S
    whole = conductance_matrix(Scene(s0.merged()), SIGMA, edge_length_m=edge_length_m).K_S
    W = s0.merge_matrix()
    identity = float(row_relative(W.T @ K0 @ W, whole).max())
    K = conductance_matrix(Scene(STUDY_SENSOR), SIGMA, edge_length_m=edge_length_m).K_S
    spreads = []
    for j, e in enumerate(STUDY_SENSOR.electrodes):
        if e.is_split:
            I = K[np.asarray(STUDY_SENSOR.numbers_of(j)) - 1, STUDY_SENSOR.emitter - 1]
            spreads.append(float(np.ptp(I) / np.abs(I).mean()))
    return identity, max(spreads), K


# ---------------------------------------------------------------------------------------------------- 3
def bempp_agreement(edge_length_m):
    from electrosense.bem.boundary_conditions import WaterBoundary
    from electrosense.bem.symmetric import solve_symmetric
    from electrosense.meshes.sector_mesh import block_symmetry
    from electrosense.meshes.sensor_mesh import mesh_sensor
    from electrosense.validation.studies.bempp_sensor import bempp_available, bempp_conductance

    if not bempp_available():
        return None
    s = STUDY_SENSOR
    mesh = mesh_sensor(s, edge_length_m=edge_length_m)
    order, mirror = block_symmetry(s)
    ours = solve_symmetric(WaterBoundary.from_meshes(mesh, emitter=s.emitter), 1.0, None, s.emitter, order=order,
                           mirror=mirror).K_S
    t0 = time.perf_counter()
    theirs = bempp_conductance(mesh, 1.0, s.emitter).K_S
    return {"triangles": mesh.n_triangles, "max_of_row_max": float(row_relative(ours, theirs).max()),
            "mean_of_row_max": float(row_relative(ours, theirs).mean()), "bempp_s": time.perf_counter() - t0}


# ---------------------------------------------------------------------------------------------------- 4
def cold_timing(sensor: SensorDescription, folder: Path):
    """Wall and CPU seconds of ``esense conductance --sensor FILE --unbounded`` with an empty cache."""
    path = folder / f"{sensor.name}.json"
    save_sensor(sensor, path)
    env = dict(os.environ, ESENSE_CACHE_DIR=tempfile.mkdtemp(prefix="esense-cold-", dir=folder))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    command = "import sys; from electrosense.validation.cli import main; sys.argv[0] = 'esense'; main()"
    run = subprocess.run([sys.executable, "-c", command, "conductance", "--sensor", str(path),
                          "--unbounded", "--json", str(folder / f"{sensor.name}.K.json")],
                         capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if run.returncode:
        raise RuntimeError(f"esense conductance failed: {run.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    triangles = json.loads((folder / f"{sensor.name}.K.json").read_text()).get("triangles")
    return wall, cpu, triangles


# ---------------------------------------------------------------------------------------------------- 5
ENTRIES = {"sector self K[2,2]": (1, 1), "neighbour sector K[2,3]": (1, 2), "opposite sector K[2,4]": (1, 3),
           "sector-emitter K[2,11]": (1, 10), "cap-emitter K[1,11]": (0, 10)}


def _order_and_limit(v, ratio):
    """Observed order from three values refined by ``ratio`` each, and the Richardson limit (order 1 where the
    differences do not shrink monotonically)."""
    d1, d2 = v[1] - v[0], v[2] - v[1]
    p = float(np.log(abs(d1 / d2)) / np.log(ratio)) if d2 != 0 and d1 * d2 > 0 else float("nan")
    return p, v[2] + d2 / (ratio ** (p if np.isfinite(p) and p > 0.3 else 1.0) - 1)


def sector_edge_refinement(out: Path, edge_factor=1.4, levels=(6.0, 12.0, 24.0, 48.0)):
    """The sector edges' family: the spacing at the sector edges halved level by level (``sector_refinement``
    doubled, ``sector_grading - 1`` halved; the rings along the axis unchanged), surface solutions.

    The default mesh is the level 12; its edge-corrected K is ``2 K_12 - K_6`` (the Richardson term of
    :func:`electrosense.bem.edge_correction.sector_edge_correction`) plus the axial correction, which these meshes
    share. Returns the surface K per level, the observed order (12, 24, 48) and the corrected K's distance from
    the limit, entry by entry.
    """
    from electrosense.bem.boundary_conditions import WaterBoundary
    from electrosense.bem.symmetric import solve_symmetric
    from electrosense.meshes.sector_mesh import DEFAULT_SECTOR_GRADING, block_symmetry
    from electrosense.meshes.sensor_mesh import default_edge_length_m, mesh_sensor

    s = STUDY_SENSOR
    h = edge_factor * default_edge_length_m(s)
    order, mirror = block_symmetry(s)
    K, tri = {}, {}
    for level in levels:
        grading = 1 + (DEFAULT_SECTOR_GRADING - 1) * 12.0 / level
        mesh = mesh_sensor(s, edge_length_m=h, sector_refinement=level, sector_grading=grading)
        t0 = time.perf_counter()
        K[level] = solve_symmetric(WaterBoundary.from_meshes(mesh, emitter=s.emitter), 1.0, None, s.emitter,
                                   order=order, mirror=mirror).K_S
        tri[level] = mesh.n_triangles
        print(f"  sector refinement {level:g}: {mesh.n_triangles} triangles, {time.perf_counter() - t0:.1f} s",
              flush=True)
    result = {}
    for name, (i, j) in ENTRIES.items():
        v = np.array([K[level][i, j] for level in levels[1:]])
        p, limit = _order_and_limit(v, 2.0)
        corrected = 2 * K[levels[1]][i, j] - K[levels[0]][i, j]
        result[name] = {"surface": [K[level][i, j] for level in levels], "order": p,
                        "surface_default_error": float(v[0] / limit - 1),
                        "corrected_default_error": float(corrected / limit - 1),
                        "row_max": float(np.abs(K[levels[-1]][i]).max()),
                        "corrected_default_error_of_row_max": float((corrected - limit) / np.abs(K[levels[-1]][i]).max())}
    _plot_sector_refinement(out / "refinement.png", levels, tri, K, result)
    return result


def _plot_sector_refinement(path, levels, tri, K, result):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    spacing = 12.0 / np.array(levels)          # sector-edge spacing relative to the default's
    for k, (name, r) in enumerate(result.items()):
        v = np.array(r["surface"])
        limit = v[1] / (1 + r["surface_default_error"])
        ax.loglog(spacing[1:], np.abs(v[1:] / limit - 1), "-o", color=f"C{k}", label=f"{name}: p = {r['order']:.2f}")
        ax.loglog([1.0], [abs(r["corrected_default_error"]) + 1e-7], "*", color=f"C{k}", ms=11)
    ax.loglog(spacing[1:], 0.01 * spacing[1:], ":", color="0.5", label="order 1")
    ax.set_xlabel("spacing at the sector edges / the default's")
    ax.set_ylabel("|K / Richardson limit - 1|")
    ax.set_title("Surface K under sector-edge refinement (stars: the default, corrected)", fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def mesh_refinement(factors=(1.4, 1.0, 1 / 1.4)):
    """The corrected free-space K at three edge lengths (the whole mesh refined): how much it still moves."""
    from electrosense.bem.solve import solve_scene
    from electrosense.meshes.scene import Scene
    from electrosense.meshes.sensor_mesh import default_edge_length_m

    s = STUDY_SENSOR
    h0 = default_edge_length_m(s)
    rows = []
    for f in factors:
        sol = solve_scene(Scene(s), 1.0, edge_length_m=h0 * f)
        rows.append((sol.info["triangles"], sol.K_S.copy(), sol.K_surface_S.copy()))
        print(f"  edge length {h0 * f * 1e3:.2f} mm: {sol.info['triangles']} triangles", flush=True)
    out = {}
    for name, (i, j) in ENTRIES.items():
        row_max = np.abs(rows[-1][1][i]).max()
        out[name] = {"triangles": [r[0] for r in rows], "corrected": [float(r[1][i, j]) for r in rows],
                     "surface": [float(r[2][i, j]) for r in rows],
                     "corrected_spread_of_row_max": float(np.ptp([r[1][i, j] for r in rows]) / row_max),
                     "surface_spread_of_row_max": float(np.ptp([r[2][i, j] for r in rows]) / row_max)}
    return out


# ---------------------------------------------------------------------------------------------------- 6
def tank_passes(edge_length_m, n_x, distances=(0.03, 0.05, 0.07, 0.10)):
    """Poses (P, 4) of the wall passes (+y then -y wall, each distance) and their (side, distance) labels."""
    R = STUDY_SENSOR.radius_m
    x = np.linspace(-0.25, 0.25, n_x)
    poses, labels = [], []
    for side in (+1, -1):
        for d in distances:
            y = side * (0.5 - R - d)
            poses += [[xi, y, 0.0, 0.0] for xi in x]
            labels += [(side, d)] * n_x
    return np.array(poses), labels


def psm_against_bem(out: Path, edge_length_m, n_x):
    from electrosense.bem.sweep import PoseSweep
    from electrosense.meshes.objects import Sphere
    from electrosense.meshes.tank import Tank
    from electrosense.psm.sectors import sector_conductance
    from electrosense.validation.simulation.models import calibrated_sector_psm

    s = STUDY_SENSOR
    tank = Tank((1.0, 1.0, 1.0))
    e = s.emitter - 1
    receivers = np.asarray(s.receivers) - 1
    split, W = s.lateral_weights()
    model = calibrated_sector_psm(s, edge_length_m)
    poses, labels = tank_passes(edge_length_m, n_x)
    t0 = time.perf_counter()
    bem = -PoseSweep(s, tank, sigma_S_per_m=SIGMA, edge_length_m=edge_length_m).conductance(poses, progress=True).K_S
    t_bem = time.perf_counter() - t0
    t0 = time.perf_counter()
    psm = -sector_conductance(model, poses, SIGMA, tank).K_S
    t_psm = time.perf_counter() - t0
    Ib, Ip = bem[:, :, e], psm[:, :, e]
    current_error = np.abs(Ip[:, receivers] / Ib[:, receivers] - 1)
    lat_b, lat_p = Ib @ W.T, Ip @ W.T
    rms = np.sqrt(np.mean((lat_p - lat_b) ** 2, axis=0) / np.mean(lat_b ** 2, axis=0))
    side = np.array([lab[0] for lab in labels])
    dist = np.array([lab[1] for lab in labels])
    sign_ok = all(np.all(np.sign(lat_b[(side == 1) & (dist == d)].mean(axis=0))
                         == -np.sign(lat_b[(side == -1) & (dist == d)].mean(axis=0)))
                  and np.all(np.sign(lat_p[(side == 1) & (dist == d)].mean(axis=0))
                             == np.sign(lat_b[(side == 1) & (dist == d)].mean(axis=0)))
                  for d in np.unique(dist))
    per_distance = {float(d): np.sqrt(np.mean((lat_p[dist == d] - lat_b[dist == d]) ** 2, axis=0)
                                      / np.mean(lat_b[dist == d] ** 2, axis=0)).tolist() for d in np.unique(dist)}
    # a pass beside a conducting sphere (radius 2 cm, centre 7 cm from the path), on either side
    x = np.linspace(-0.2, 0.2, n_x)
    sphere_rows = {}
    for sgn in (+1, -1):
        sphere = Sphere(centre_m=(0.0, sgn * 0.07, 0.0), conductivity_S_per_m=float("inf"), radius_m=0.02)
        sp = np.column_stack([x, np.zeros_like(x), np.zeros_like(x), np.zeros_like(x)])
        b = -PoseSweep(s, tank, objects=(sphere,), sigma_S_per_m=SIGMA,
                       edge_length_m=edge_length_m).conductance(sp, progress=True).K_S[:, :, e]
        p = -sector_conductance(model, sp, SIGMA, tank, objects=(sphere,)).K_S[:, :, e]
        sphere_rows[sgn] = (b, p)
    sb = np.concatenate([sphere_rows[1][0], sphere_rows[-1][0]])
    sp_ = np.concatenate([sphere_rows[1][1], sphere_rows[-1][1]])
    sphere_current = float(np.abs(sp_[:, receivers] / sb[:, receivers] - 1).mean())
    sphere_rms = np.sqrt(np.mean((sp_ @ W.T - sb @ W.T) ** 2, axis=0) / np.mean((sb @ W.T) ** 2, axis=0))
    _plot_lateral(out / "lateral_walls.png", out / "lateral_sphere.png", poses, labels, lat_b, lat_p, split, x,
                  {k: (v[0] @ W.T, v[1] @ W.T) for k, v in sphere_rows.items()})
    return {"poses": len(poses), "bem_s": t_bem, "psm_s": t_psm,
            "current_mean": float(current_error.mean()), "current_max": float(current_error.max()),
            "lateral_rms": rms.tolist(), "lateral_rms_per_distance": per_distance, "sign_change": bool(sign_ok),
            "sphere_current_mean": sphere_current, "sphere_lateral_rms": sphere_rms.tolist(),
            "split": [int(j) + 1 for j in split]}


def _plot_lateral(path_walls, path_sphere, poses, labels, lat_b, lat_p, split, x_sphere, sphere):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = np.array(labels)
    fig, axes = plt.subplots(1, len(split), figsize=(5.2 * len(split), 4.0), squeeze=False)
    for c, j in enumerate(split):
        ax = axes[0, c]
        for k, d in enumerate(sorted(set(labels[:, 1]))):
            for side, marker in ((1, "o"), (-1, "s")):
                sel = (labels[:, 0] == side) & (labels[:, 1] == d)
                x = poses[sel, 0]
                ax.plot(x, 1e6 * lat_p[sel, c], "-", color=f"C{k}",
                        label=f"{d * 100:.0f} cm from the wall" if side > 0 else None)
                ax.plot(x, 1e6 * lat_b[sel, c], marker, color=f"C{k}", mfc="none", ms=4)
        ax.axhline(0, color="0.6", lw=0.6)
        ax.set_title(f"electrode {j + 1} ({STUDY_SENSOR.electrodes[j].sectors} sectors): left - right")
        ax.set_xlabel("sensor position x (m), passes parallel to the wall")
        ax.set_ylabel("lateral signal (uA at 1 V)")
        ax.grid(True, alpha=0.3)
        if c == 0:
            ax.legend(fontsize=6.5, title="PSM lines; BEM: o +y wall, s -y wall", title_fontsize=7)
    fig.tight_layout()
    fig.savefig(path_walls, dpi=130)
    plt.close(fig)
    fig, axes = plt.subplots(1, len(split), figsize=(5.2 * len(split), 4.0), squeeze=False)
    for c, j in enumerate(split):
        ax = axes[0, c]
        for k, (sgn, (b, p)) in enumerate(sorted(sphere.items())):
            ax.plot(x_sphere, 1e6 * p[:, c], "-", color=f"C{k}", label=f"sphere at y = {sgn * 7:+d} cm: PSM")
            ax.plot(x_sphere, 1e6 * b[:, c], "o", color=f"C{k}", mfc="none", ms=4, label="BEM")
        ax.axhline(0, color="0.6", lw=0.6)
        ax.set_title(f"electrode {j + 1}: past a conducting sphere (r = 2 cm)")
        ax.set_xlabel("sensor position x (m), along y = 0")
        ax.set_ylabel("lateral signal (uA at 1 V)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path_sphere, dpi=130)
    plt.close(fig)


# ---------------------------------------------------------------------------------------------------- 7
def cramer_rao(out: Path, edge_length_m):
    """CRB of y and yaw ((x, y, yaw) unknown) beside the +y wall, sector sensor against whole rings."""
    from electrosense.bem.lateral import free_space_response
    from electrosense.meshes.tank import Tank
    from electrosense.psm.sectors import SectorModel, sector_conductance

    tank = Tank((1.0, 1.0, 1.0))
    R = STUDY_SENSOR.radius_m
    cases = [(d, yaw) for d in (0.03, 0.05, 0.10) for yaw in (0.0, 0.3)]
    rows = {}
    for name, sensor in (("sectors", STUDY_SENSOR), ("whole rings", STUDY_SENSOR.merged())):
        model = SectorModel.from_response(free_space_response(sensor, SIGMA, edge_length_m=edge_length_m))
        e = sensor.emitter - 1
        receivers = np.asarray(sensor.receivers) - 1
        bounds = []
        for d, yaw in cases:
            # the sensor's nearest point d from the wall: its centre further in when turned
            y = 0.5 - d - R - 0.5 * STUDY_SENSOR.length_m * abs(np.sin(yaw))
            pose = np.array([0.0, y, 0.0, yaw])
            steps = np.array([1e-4, 1e-4, 1e-4])
            idx = [0, 1, 3]
            shifted = []
            for k, h in zip(idx, steps):
                for sgn in (1, -1):
                    p = pose.copy()
                    p[k] += sgn * h
                    shifted.append(p)
            I = -sector_conductance(model, np.vstack([pose] + shifted), SIGMA, tank).K_S[:, receivers, e]
            J = np.stack([(I[1 + 2 * a] - I[2 + 2 * a]) / (2 * h) for a, h in enumerate(steps)], axis=1)
            noise = BENCH_CURRENT_NOISE_REL * np.abs(I[0])
            F = (J / noise[:, None] ** 2).T @ J
            crb = np.linalg.inv(F)
            bounds.append((float(np.sqrt(crb[1, 1])), float(np.sqrt(crb[2, 2]))))
        rows[name] = bounds
    _plot_crb(out / "crb.png", cases, rows)
    return cases, rows


def _plot_crb(path, cases, rows):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9.6, 3.8))
    x = np.arange(len(cases))
    for k, (what, unit, scale) in enumerate((("lateral position y", "mm", 1e3), ("heading", "mrad", 1e3))):
        ax = axes[k]
        for m, (name, b) in enumerate(rows.items()):
            ax.bar(x + (m - 0.5) * 0.38, [scale * v[k] for v in b], 0.38, label=name)
        ax.set_yscale("log")
        ax.set_xticks(x, [f"{d * 100:.0f} cm\nyaw {yaw:.1f}" for d, yaw in cases], fontsize=7)
        ax.set_ylabel(f"CRB standard deviation ({unit})")
        ax.set_title(f"{what}, beside a wall ((x, y, yaw) unknown)", fontsize=9)
        ax.grid(True, axis="y", which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


# ------------------------------------------------------------------------------------------------- main
def _save(out: Path, figures: dict, lines: list):
    """figures.json updated (a partial run keeps the other figures), summary.txt appended."""
    path = out / "figures.json"
    old = json.loads(path.read_text()) if path.exists() else {}
    old.update(json.loads(json.dumps(figures, default=float)))
    path.write_text(json.dumps(old, indent=1) + "\n")
    with open(out / "summary.txt", "a") as f:
        f.write("\n".join(lines) + "\n")



def main(argv=None):
    ap = argparse.ArgumentParser(prog="sector_sensor", description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="sector_sensor_study", help="folder of the figures and figures.json")
    ap.add_argument("--quick", action="store_true", help="coarser meshes, fewer poses (a smoke run)")
    ap.add_argument("--skip-bempp", action="store_true")
    ap.add_argument("--skip-timing", action="store_true")
    ap.add_argument("--skip-refinement", action="store_true")
    ap.add_argument("--only-refinement", action="store_true", help="stop after the refinement (and what precedes "
                    "it unless skipped); figures.json is updated, not replaced")
    ap.add_argument("--bempp-edge-length", type=float, default=None,
                    help="edge length of the mesh both codes solve (m); default 1.5 x the default mesh's")
    args = ap.parse_args(argv)
    from electrosense.meshes.sensor_mesh import default_edge_length_m, mesh_sensor

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    h = 1.8 * default_edge_length_m(STUDY_SENSOR) if args.quick else None
    n_x = 5 if args.quick else 9
    figures = {"sensor": STUDY_SENSOR.to_dict(),
               "default_triangles": mesh_sensor(STUDY_SENSOR).n_triangles}
    lines = []

    def report(what, measured, goal, ok=None):
        mark = "" if ok is None else ("  ok" if ok else "  MISSED")
        lines.append(f"{what:58s} {measured:>26s}   goal {goal}{mark}")
        print(lines[-1], flush=True)

    print(f"sensor: {STUDY_SENSOR.n_electrodes} electrodes {STUDY_SENSOR.electrode_labels}, emitter "
          f"{STUDY_SENSOR.emitter}; default mesh {figures['default_triangles']} triangles", flush=True)
    identity, spread, _ = identity_and_equal_currents(h)
    figures.update(identity=identity, equal_currents_spread=spread)
    report("all-sectors identity (no gaps), of the row maximum", f"{100 * identity:.3f} %", "< 0.3 %",
           identity < 3e-3)
    report("a ring's sector currents, cap emitting (spread / mean)", f"{100 * spread:.2e} %", "< 0.1 %",
           spread < 1e-3)
    if not args.skip_bempp:
        hb = args.bempp_edge_length or 1.5 * default_edge_length_m(STUDY_SENSOR) * (1.3 if args.quick else 1.0)
        b = bempp_agreement(hb)
        if b is None:
            report("bempp-cl on the same mesh", "not installed", "< 1.5 %")
        else:
            figures["bempp"] = b
            report(f"bempp-cl on the same mesh ({b['triangles']} triangles), max of row max",
                   f"{100 * b['max_of_row_max']:.2f} %", "< 1.5 %", b["max_of_row_max"] < 0.015)
    if not args.skip_timing:
        with tempfile.TemporaryDirectory() as folder:
            for sensor, label in ((STUDY_SENSOR, "4-fold"), (mirror_sensor(), "mirror only")):
                wall, cpu, tri = cold_timing(sensor, Path(folder))
                figures[f"cold_{label}"] = {"wall_s": wall, "cpu_s": cpu, "triangles": tri}
                report(f"free-space K from an empty cache ({label}, {tri} triangles)",
                       f"wall {wall:.1f} s, CPU {cpu:.1f} s", "< 30 s", wall < 30)
    if not args.skip_refinement and not args.quick:
        edges = sector_edge_refinement(out)
        figures["sector_edge_refinement"] = edges
        for name, r in edges.items():
            report(f"sector-edge refinement: {name}",
                   f"p = {r['order']:.2f}; default {100 * r['corrected_default_error']:+.3f} % "
                   f"({100 * r['surface_default_error']:+.2f} % raw)", "an observed order")
        meshes = mesh_refinement()
        figures["mesh_refinement"] = meshes
        for name, r in meshes.items():
            report(f"whole mesh x1.4, x1, /1.4: {name} moves by",
                   f"{100 * r['corrected_spread_of_row_max']:.3f} % ({100 * r['surface_spread_of_row_max']:.2f} %"
                   " raw)", "of the row max")
    if args.only_refinement:
        _save(out, figures, lines)
        return
    tank = psm_against_bem(out, h, n_x)
    figures["tank"] = tank
    report(f"PSM vs BEM in the tank, sector currents ({tank['poses']} poses)",
           f"mean {100 * tank['current_mean']:.3f} %", "< 1 % on average", tank["current_mean"] < 0.01)
    for j, r in zip(tank["split"], tank["lateral_rms"]):
        report(f"lateral signal of electrode {j}, passes 3-10 cm from a wall", f"RMS {100 * r:.1f} %", "< 10 %",
               r < 0.1)
    report("lateral signal changes sign with the wall's side", str(tank["sign_change"]), "True", tank["sign_change"])
    report("PSM vs BEM past a sphere, sector currents", f"mean {100 * tank['sphere_current_mean']:.3f} %", "(report)")
    for j, r in zip(tank["split"], tank["sphere_lateral_rms"]):
        report(f"lateral signal of electrode {j}, past a sphere", f"RMS {100 * r:.1f} %", "(report)")
    cases, crb = cramer_rao(out, h)
    figures["crb"] = {"cases": cases, **crb}
    for (d, yaw), s_b, w_b in zip(cases, crb["sectors"], crb["whole rings"]):
        report(f"CRB beside a wall, {d * 100:.0f} cm, yaw {yaw:.1f}: y, heading (whole / sectors)",
               f"{w_b[0] / s_b[0]:.1f}x, {w_b[1] / s_b[1]:.1f}x", "(report)")
    _save(out, figures, lines)
    print(f"figures: {out}/refinement.png, lateral_walls.png, lateral_sphere.png, crb.png; numbers: "
          f"{out}/figures.json", flush=True)


if __name__ == "__main__":
    main()
