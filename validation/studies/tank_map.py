"""Tank map study: a map of a random unseen sensor in a random tank, against fresh BEM solves, timed, localising.

Goals (issue 23), printed beside every figure:

* the map within a third of the bench noise of the BEM at random poses it was not built on (0.017 % RMS,
  0.05 % at most), sensor tips 5 mm to 20 cm from a wall, the BEM solved on another tank mesh (graded towards the
  test poses); besides, ``--near-wall-poses`` poses 5-15 mm from a wall (:func:`check_near_wall`), where a
  20-pose draw puts two or three and the map is hardest, and in a box ``--corner-poses`` poses 5-12 mm from two
  walls at once (:func:`check_corners`), which a 20-pose draw seldom holds;
* built in under 5 minutes on 2 cores from an empty cache (wall and CPU time);
* 10 000 poses/s or more with the pose Jacobian on one core, and through ``esense sweep --model map``;
* on a virtual-bench log (BEM physics, 0.05 % noise) passing 2 cm from a wall: the map's position error within
  1.5x its Cramer-Rao bound and under 1 mm RMS, the PSM's beside it; the same for a conducting ball a second
  log passes (meshed in that log's BEM; its position from the currents, ``esense localise --object-at``).

Also written: ``map_vs_psm.png``, the map's and the PSM's error against the BEM on a line from wall to wall
(the README's figure), and ``localise.png``.

With ``--objects N``, N random fixed objects (:func:`random_objects`: conducting balls and insulating poles at the
sensor's depth) stand in the tank: they break its symmetry (the map is not folded) and the near-wall check
counts them as walls; the localisation and the ``esense sweep`` grid, which would cross them, are left out.

Run: ``esense study tank_map [--seed N] [--minutes M] [--cylinder] [--band] [--objects N] [--near-wall-poses N]
[--corner-poses N] [-o DIR]``.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import tempfile
import time
from pathlib import Path

from electrosense.validation.simulation.workers import one_thread_environment

one_thread_environment()

import numpy as np  # noqa: E402

#: what the study needs beyond the base install (its speed check runs `esense sweep`): checked before the build
NEEDS_EXTRAS = ("sweep",)

GOALS = {"rms": 1.7e-4, "max": 5e-4, "build_s": 300.0, "poses_per_s": 1e4, "loc_over_crb": 1.5, "loc_rms_m": 1e-3}
#: radius (m) of the conducting ball the object pass goes by (meshed in the virtual bench's BEM)
BALL_M = 0.015


def _cpu_s() -> float:
    """CPU seconds of this process and its finished children (the BEM workers)."""
    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def _line(label, value, goal, fmt="{:.4g}", better="below"):
    ok = value <= goal if better == "below" else value >= goal
    print(f"  {label:<58s} {fmt.format(value):>12s}   goal {'<=' if better == 'below' else '>='} "
          f"{fmt.format(goal):<10s} {'ok' if ok else 'MISSED'}")
    return ok


def random_scene(rng, cylinder: bool):
    from electrosense.meshes.cylinder_tank import CylinderTank
    from electrosense.meshes.tank import Tank
    from electrosense.validation.diagnosis.unseen import random_sensor

    sensor = random_sensor(rng, int(rng.integers(4, 6)), name="study-sensor")
    if cylinder:
        r, h = float(rng.uniform(0.3, 0.45)), float(rng.uniform(0.3, 0.5))
        tank = CylinderTank(r, h, h * float(rng.uniform(0.75, 0.95)))
    else:
        lx, ly, lz = rng.uniform(0.5, 0.8), rng.uniform(0.4, 0.65), rng.uniform(0.3, 0.45)   # to the mm, as typed
        tank = Tank((round(lx, 3), round(ly, 3), round(lz, 3)), round(lz * rng.uniform(0.75, 0.95), 3))
    z_mid = 0.5 * (tank.floor_z_m + tank.free_surface_z_m)
    z = z_mid + float(rng.uniform(-0.2, 0.2)) * (tank.free_surface_z_m - tank.floor_z_m)
    return sensor, tank, round(z, 4)


def random_objects(rng, sensor, tank, z, n: int) -> tuple:
    """``n`` fixed objects at the sensor's depth ``z``: conducting balls (radius 2-3.5 cm) and insulating vertical
    poles (radius 1.5-2.5 cm, from 1 cm above the floor to 1 cm below the free surface), in turn, each 6 cm or more of water
    from the walls and from the others, so that the sensor can pass between them.

    >>> from electrosense.meshes.tank import Tank
    >>> from electrosense.meshes.sensor import preset
    >>> objs = random_objects(np.random.default_rng(0), preset("angels-4"), Tank((1.0, 0.8, 0.5)), 0.0, 2)
    >>> [type(o).__name__ for o in objs], objs[0].is_conducting, objs[1].is_insulating
    (['Sphere', 'Cylinder'], True, True)
    """
    from electrosense.meshes.objects import Cylinder, Sphere

    lo, hi = tank.water_bounds_m
    out = []
    for k in range(n):
        for _ in range(1000):
            if k % 2 == 0:
                r = float(rng.uniform(0.02, 0.035))
                cz = float(z)
            else:
                r = float(rng.uniform(0.015, 0.025))
                h = tank.free_surface_z_m - tank.floor_z_m - 0.02
                cz = tank.floor_z_m + 0.01 + 0.5 * h
            free = 0.06 + r
            if hi[0] - lo[0] < 2 * free or hi[1] - lo[1] < 2 * free:
                raise ValueError(f"no room for an object of radius {r:.3f} m 6 cm from the walls of {tank}")
            c = np.array([rng.uniform(lo[0] + free, hi[0] - free), rng.uniform(lo[1] + free, hi[1] - free)])
            if hasattr(tank, "radius_m") and np.hypot(*c) + free > float(tank.radius_at(cz)):   # a round tank
                continue
            if all(np.hypot(*(c - o.centre_m[:2])) - o.radius_m - r >= 0.06 + 2 * sensor.radius_m for o in out):
                break
        else:
            raise ValueError(f"could not place {n} objects 6 cm apart in {tank}")
        centre = (round(float(c[0]), 4), round(float(c[1]), 4), round(cz, 4))
        out.append(Sphere(centre, conductivity_S_per_m="conducting", radius_m=round(r, 4), name=f"ball {k + 1}")
                   if k % 2 == 0 else
                   Cylinder(centre, conductivity_S_per_m="insulating", radius_m=round(r, 4), height_m=round(h, 4),
                            name=f"pole {k + 1}"))
    return tuple(out)


def test_poses(sensor, tank, z, rng, n, band=None, gap_m=(0.005, 0.2), objects=()):
    """``n`` random poses with the tips 5 mm to 20 cm (``gap_m``) from the nearest wall or object."""
    from electrosense.validation.simulation.tank_map import sensor_wall_gap_m

    lo, hi = tank.water_bounds_m
    out = []
    while len(out) < n:
        zz = z if band is None else rng.uniform(*band)
        p = np.array([rng.uniform(lo[0], hi[0]), rng.uniform(lo[1], hi[1]), zz, rng.uniform(-np.pi, np.pi)])
        g = sensor_wall_gap_m(sensor, tank, p[None], objects)[0]
        if gap_m[0] <= g <= gap_m[1]:
            out.append(p)
    return np.array(out)


#: the gaps (m) of the study's near-wall check (from the nearest wall, or, in a band, floor or free surface):
#: where the map is hardest and a 20-pose draw puts two or three
NEAR_WALL_GAP_M = (0.005, 0.015)


def check_near_wall(m, sensor, tank, z, seed: int, n: int, band=None, objects=(), n_sensor_check: int = 2) -> dict:
    """The map against the BEM at ``n`` random poses with gaps in :data:`NEAR_WALL_GAP_M` (from a wall or an
    object), each on a tank mesh graded to it alone (as the map's nodes: the interpolation's error,
    :func:`errors_on_own_tank_meshes`), drawn from their own seed (the study's other draws unchanged by ``n``);
    and at the first ``n_sensor_check`` of them the reference's own sensor-mesh error (``bem_sensor``,
    :func:`reference_sensor_mesh_error`): near a wall it can exceed the map's (seed 4: 0.06-0.09 % at 2 cm)."""
    from electrosense.validation.simulation.tank_map import sensor_wall_gap_m

    P = test_poses(sensor, tank, z, np.random.default_rng([seed, 1]), n, band, NEAR_WALL_GAP_M, objects)
    out, K = errors_at(m, sensor, tank, P, objects)
    out["gaps_m"] = sensor_wall_gap_m(sensor, tank, P, objects).tolist()
    if n_sensor_check and m.focus_m is None:
        err = reference_sensor_mesh_error(m, sensor, tank, P[:n_sensor_check], objects, K_reference=K[:n_sensor_check])
        out.update(bem_sensor_rms=float(np.sqrt(np.mean(err**2))), bem_sensor_max=float(np.abs(err).max()),
                   bem_sensor_errors=err.tolist())
    return out


def error_split(m, sensor, tank, P, K_reference, objects=()) -> dict:
    """The map's error at ``P`` split into its two parts, with the map's coarse BEM solved there
    (:attr:`~electrosense.validation.simulation.tank_map.TankMap.fidelities`): ``interpolation``, the coarse
    interpolant against the coarse BEM, and ``correction``, the interpolated correction to the reference against
    the true one, log(K_ref / K_coarse) (relative errors of the receiver currents, RMS and largest; their sum is
    the map's error to first order). Which of the two to spend poses on: more nodes, or more reference poses.
    Empty for a map without a correction or of a format before 10."""
    from electrosense.bem import PoseSweep
    from electrosense.validation.simulation.tank_map import each_on_its_own_tank_mesh

    if m.coarse_factor <= 1.0 or not len(m.ref_index):
        return {}
    try:
        options = dict(m.fidelities["coarse"])
    except ValueError:   # a map before format 10: its coarse BEM is not one the map can name
        return {}
    within_m = options.pop("image_faces_within_m", None)
    K_coarse = each_on_its_own_tank_mesh(PoseSweep(sensor, tank, objects, 1.0, **options), P, within_m)
    e = sensor.emitter - 1
    r = [k for k in range(sensor.n_electrodes) if k != e]
    K_map, K_map_coarse = m.conductance(P), m.conductance(P, correction=False)
    interpolation = K_map_coarse[:, r, e] / K_coarse[:, r, e] - 1
    correction = (K_map[:, r, e] / K_map_coarse[:, r, e]) / (K_reference[:, r, e] / K_coarse[:, r, e]) - 1
    return {f"{name}_{stat}": float(f(err)) for name, err in (("interpolation", interpolation),
                                                              ("correction", correction))
            for stat, f in (("rms", lambda a: np.sqrt(np.mean(a**2))), ("max", lambda a: np.abs(a).max()))}


def reference_sensor_mesh_error(m, sensor, tank, P, objects=(), finer: float = 0.7, K_reference=None) -> np.ndarray:
    """Relative error (P, m) of the receiver currents of a map's reference BEM (format 10 and later: each pose on a tank mesh
    of its own, the near faces image planes; ``K_reference`` where already solved) against the same BEM on a
    sensor mesh ``finer`` x the reference's edge: the reference's own discretisation, which the map carries."""
    e = sensor.emitter - 1
    r = [k for k in range(sensor.n_electrodes) if k != e]
    K = reference_bem(m, sensor, tank, P, objects) if K_reference is None else K_reference
    K_fine = reference_bem(m, sensor, tank, P, objects, edge_length_m=finer * m.bem_options["edge_length_m"])
    return K[:, r, e] / K_fine[:, r, e] - 1


def reference_bem(m, sensor, tank, P, objects=(), **override) -> np.ndarray:
    """K (P, n, n) at 1 S/m of the BEM a map of format 10 or later reproduces (its options, each pose on a tank mesh of its
    own, the tank's flat faces within ``m.reference_images_m`` image planes), with ``override`` of its options."""
    from electrosense.bem import PoseSweep
    from electrosense.validation.simulation.tank_map import each_on_its_own_tank_mesh

    sweep = PoseSweep(sensor, tank, objects, 1.0, **{**m.bem_options, **override})
    return each_on_its_own_tank_mesh(sweep, P, m.reference_images_m)


def near_object_poses(sensor, tank, z, rng, n, objects, band=None, gap_m=NEAR_WALL_GAP_M) -> np.ndarray:
    """``n`` random poses with the sensor ``gap_m`` from one of the fixed ``objects`` (each in turn) and no nearer
    a wall than the gap's low end; random headings."""
    from electrosense.validation.simulation.tank_map import boundary_gaps_m

    reach = 0.5 * sensor.length_m + sensor.radius_m + gap_m[1]
    n_walls = boundary_gaps_m(sensor, tank, np.zeros((1, 4))).shape[1]
    out, tries = [], 0
    while len(out) < n:
        tries += 1
        if tries > 200_000:
            raise ValueError(f"no pose {gap_m[0]}-{gap_m[1]} m from {objects[len(out) % len(objects)]} keeps the "
                             f"sensor {gap_m[0]} m from everything else")
        k = len(out) % len(objects)
        o = objects[k]
        zz = z if band is None else rng.uniform(*band)
        c = np.asarray(o.centre_m[:2]) + rng.uniform(-1, 1, 2) * (o.radius_m + reach)
        p = np.array([c[0], c[1], zz, rng.uniform(-np.pi, np.pi)])
        g = boundary_gaps_m(sensor, tank, p[None], objects)[0]
        if gap_m[0] <= g[n_walls + k] <= gap_m[1] and g.min() >= gap_m[0]:
            out.append(p)
    return np.array(out)


def check_near_objects(m, sensor, tank, z, seed: int, n: int, objects, band=None) -> dict:
    """The map against the BEM at ``n`` random poses 5-15 mm from a fixed object (:func:`near_object_poses`), each
    on a tank mesh graded to it alone, drawn from their own seed, its error split as near a wall (:func:`error_split`)."""
    from electrosense.validation.simulation.tank_map import sensor_wall_gap_m

    P = near_object_poses(sensor, tank, z, np.random.default_rng([seed, 4]), n, objects, band)
    out, _ = errors_at(m, sensor, tank, P, objects)
    return {**out, "gaps_m": sensor_wall_gap_m(sensor, tank, P, objects).tolist()}


def errors_at(m, sensor, tank, P, objects=()) -> tuple[dict, np.ndarray]:
    """The map's error against the reference BEM at the poses ``P`` (:func:`errors_on_own_tank_meshes`): its RMS
    and largest, the map's own estimate there (RMS), the poses, every receiver's error and its split into the
    coarse interpolant's and the correction's (:func:`error_split`); and that BEM's K (P, n, n)."""
    err, K = errors_on_own_tank_meshes(m, sensor, tank, P, objects)
    return {"rms": float(np.sqrt(np.mean(err**2))), "max": float(np.abs(err).max()),
            "estimated_rms": float(np.sqrt(np.mean(m.estimated_error(P) ** 2))), "poses": P.tolist(),
            "errors": err.tolist(), **error_split(m, sensor, tank, P, K, objects)}, K


#: the gaps (m) from each of two walls of the study's corner check
CORNER_GAP_M = (0.005, 0.012)


def check_corners(m, sensor, tank, z, seed: int, n: int, band=None, objects=()) -> dict:
    """The map against the BEM at ``n`` random poses 5-12 mm from two walls at once, drawn from their own seed as
    the map's band of corner poses is from its own
    (:func:`~electrosense.validation.simulation.tank_map.corner_poses`), each on a tank mesh graded to it alone
    (:func:`errors_on_own_tank_meshes`)."""
    from electrosense.validation.simulation.tank_map import corner_poses

    P = corner_poses(sensor, tank, z, np.random.default_rng([seed, 2]), n, band, CORNER_GAP_M, objects, 10**9)
    return errors_at(m, sensor, tank, P, objects)[0]


def errors_on_own_tank_meshes(m, sensor, tank, P, objects=()):
    """The map's relative error of the receiver currents (P, m) against the reference BEM solved as its nodes were,
    and that BEM's K (P, n, n): each pose on a tank mesh graded to it alone (a map of an earlier version, whose
    nodes share one tank mesh graded to the fundamental domain: on that mesh, at the folded poses)."""
    from electrosense.bem import PoseSweep

    e = sensor.emitter - 1
    r = [k for k in range(sensor.n_electrodes) if k != e]
    if m.focus_m is None:   # the reference as the map's nodes (format 10 and later: the near faces image planes)
        K = reference_bem(m, sensor, tank, P, objects)
    else:
        K = PoseSweep(sensor, tank, objects, 1.0, focus_m=m.focus_m, tank_near_ratio=None,
                      **m.bem_options).conductance(m.frame.folded(P)).K_S
        K = m.mirrored(K, P)     # back to the poses' own frame (a sector sensor's permutation)
    return m.conductance(P)[:, r, e] / K[:, r, e] - 1, K


def check_accuracy(m, sensor, tank, P, n_sensor_check: int = 4, objects=()):
    """Receiver-current errors of the map against the reference BEM (the map's sensor mesh options) at ``P``:
    ``other``: on one tank mesh graded towards all of ``P`` (a fresh BEM as a user would run it along a path);
    ``same``: each pose on a tank mesh graded to it alone, as the map's nodes were solved (the interpolation's
    error alone); ``bem_tank``: the BEM between the two; ``bem_sensor``: the BEM with its sensor mesh 0.7x the
    reference's at the first ``n_sensor_check`` poses, ``bem_tank_grading``: each of them on a tank mesh graded
    0.6x the reference's (the reference's own discretisation), ``bem_default_tank``: on the BEM's default tank
    mesh against the reference's (what a map on the default would be off by)."""
    from electrosense.bem import PoseSweep
    from electrosense.meshes.scene_mesh import trajectory_focus_m

    e = sensor.emitter - 1
    r = [k for k in range(sensor.n_electrodes) if k != e]
    focus = trajectory_focus_m(sensor, P)
    K_other = PoseSweep(sensor, tank, objects, 1.0, focus_m=focus, **m.bem_options).conductance(P).K_S
    out = {"other": m.conductance(P)[:, r, e] / K_other[:, r, e] - 1}
    out["same"], K_same = errors_on_own_tank_meshes(m, sensor, tank, P, objects)
    out["bem_tank"] = K_same[:, r, e] / K_other[:, r, e] - 1
    if n_sensor_check:
        fine = {**m.bem_options, "edge_length_m": 0.7 * m.bem_options["edge_length_m"]}
        K_fine = PoseSweep(sensor, tank, objects, 1.0, focus_m=focus, **fine).conductance(P[:n_sensor_check]).K_S
        out["bem_sensor"] = K_other[:n_sensor_check][:, r, e] / K_fine[:, r, e] - 1
        if m.focus_m is None and "tank_grading" in m.bem_options:
            from electrosense.meshes.scene_mesh import DEFAULT_TANK_GRADING

            K_tank = {}
            for name, grading in (("bem_tank_grading", 0.6 * m.bem_options["tank_grading"]),
                                  ("bem_default_tank", DEFAULT_TANK_GRADING)):
                K_tank[name] = reference_bem(m, sensor, tank, P[:n_sensor_check], objects, tank_grading=grading)
            out["bem_tank_grading"] = K_same[:n_sensor_check][:, r, e] / K_tank["bem_tank_grading"][:, r, e] - 1
            out["bem_default_tank"] = K_tank["bem_default_tank"][:, r, e] / K_same[:n_sensor_check][:, r, e] - 1
    return out


def map_vs_psm_figure(m, sensor, tank, z, out: Path, n: int = 25, objects=()):
    """The map's and the PSM's error against the BEM on a line from wall to wall (tips 5 mm from each), heading 0
    (the PSM only in a box: it has no images of a cylinder's wall); with fixed ``objects``, the poses 5 mm or more
    from them."""
    from electrosense.bem import PoseSweep
    from electrosense.meshes.objects import Sphere
    from electrosense.meshes.scene_mesh import trajectory_focus_m
    from electrosense.validation.diagnosis.anchored import psm_usable
    from electrosense.validation.report.style import colour_of, new_figure, save
    from electrosense.validation.simulation.models import calibrated_psm, pose_evaluator

    lo, hi = tank.water_bounds_m
    half = 0.5 * sensor.length_m
    x = np.linspace(lo[0] + half + 0.005, hi[0] - half - 0.005, n)
    y0 = 0.5 * (lo[1] + hi[1]) if not hasattr(tank, "radius_m") else 0.0
    P = np.c_[x, np.full(n, y0), np.full(n, z), np.zeros(n)]
    if objects:
        from electrosense.validation.simulation.tank_map import sensor_wall_gap_m

        clear = sensor_wall_gap_m(sensor, tank, P, objects) >= 0.005 - 1e-9
        x, P, n = x[clear], P[clear], int(clear.sum())
    if m.reference_images_m is not None:   # the BEM as the map's nodes: near faces images, each pose on its own
        K = reference_bem(m, sensor, tank, P, objects)
    else:
        K = PoseSweep(sensor, tank, objects, 1.0, focus_m=trajectory_focus_m(sensor, P),
                      **m.bem_options).conductance(P).K_S
    e = sensor.emitter - 1
    r = [k for k in range(sensor.n_electrodes) if k != e]
    err_map = np.abs(m.conductance(P)[:, r, e] / K[:, r, e] - 1).max(axis=1)
    psm = calibrated_psm(sensor)
    balls_only = all(isinstance(o, Sphere) for o in objects)   # the PSM's object term: a ball's dipole
    ok = psm_usable(psm, P, tank) & balls_only
    if objects and balls_only:   # and its spheres clear of the balls: it refuses the other poses (left out)
        from electrosense.psm.conductance import placement_fits

        ok &= placement_fits(psm, P, tank, objects)
    err_psm = np.full(n, np.nan)
    if ok.any():
        Kp = pose_evaluator("psm", sensor, tank, 1.0, objects, psm_model=psm).conductance(P[ok]).K_S
        err_psm[ok] = np.abs(Kp[:, r, e] / K[ok][:, r, e] - 1).max(axis=1)
    fig, axes = new_figure(1, 1, panel_size_in=(5.6, 3.4))
    ax = axes[0, 0]
    gap = np.minimum(x - half - lo[0], hi[0] - half - x) * 1e3
    ax.semilogy(x, 100 * err_map, "o-", ms=3, color=colour_of("map", 0), label="tank map")
    if ok.any():   # the PSM has no images of a cylinder's wall
        ax.semilogy(x, 100 * err_psm, "s-", ms=3, color=colour_of("psm", 1), label="PSM (complete images)")
    ax.axhline(100 * GOALS["rms"], color="0.5", ls="--", lw=1, label="a third of the bench noise")
    ax.axhline(0.05, color="0.3", ls=":", lw=1, label="bench noise")
    ax.set_xlabel("x of the sensor centre (m); heading along x")
    ax.set_ylabel("largest |model / BEM - 1| (%)")
    round_tank = hasattr(tank, "radius_m")
    several = len(objects) > 1
    objects_line = (f",\n{len(objects)} fixed object{'s' if several else ''}, poses 5 mm or more from "
                    f"{'them' if several else 'it'}") if objects else ""
    ax.set_title(f"{sensor.n_electrodes}-electrode sensor along a {'diameter' if round_tank else 'line'} of the tank,\n"
                 f"tips {gap.min():.0f} mm to {gap.max():.0f} mm from {'its wall' if round_tank else 'the end walls'}"
                 f"{'' if ok.any() else ' (the PSM: no images of a round wall)' if balls_only else ''}"
                 f"{objects_line}"
                 f"{'' if balls_only else ' (no PSM: it models balls only)'}", fontsize=9)
    ax.legend(fontsize=7)
    save(fig, out, vector=None)
    return {"x_m": x.tolist(), "map": err_map.tolist(), "psm": err_psm.tolist()}


def sweep_speed(map_path: Path, sensor, tank, z, folder: Path):
    """``esense sweep --model map`` over a 100 x 100 grid of poses: poses/s of the run and of the whole command."""
    from click.testing import CliRunner

    from electrosense.validation.cli import main

    lo, hi = tank.water_bounds_m
    pad = 0.15
    if hasattr(tank, "radius_m"):   # a square inside the circle: its corners' sensors too 6 mm off the wall
        w = (float(tank.radius_at(z)) - sensor.radius_m - 0.006 - 0.5 * sensor.length_m) / np.sqrt(2.0)
        lo, hi, pad = np.array([-w, -w]), np.array([w, w]), 0.0
    grid = f"{lo[0] + pad:.4f}:{hi[0] - pad:.4f}:100,{lo[1] + pad:.4f}:{hi[1] - pad:.4f}:100"
    out = folder / "sweep.zarr"
    t0 = time.perf_counter()
    res = CliRunner().invoke(main, ["sweep", "--model", "map", "--map", str(map_path), "--grid", grid, "--z", str(z),
                                    "--workers", "1", "-o", str(out), "--quiet"])
    wall = time.perf_counter() - t0
    if res.exit_code != 0:
        raise RuntimeError(res.output)
    line = [s for s in res.output.splitlines() if s.startswith("computed")]
    run_s = float(line[0].split(" in ")[1].split(" s")[0]) if line else wall
    return 1e4 / run_s, 1e4 / wall


def localisation_log(sensor, tank, z, folder: Path, n: int, seed: int, ball_m: float | None = None,
                     tank_grading: float | None = None, name: str | None = None, wall_images: bool = False,
                     edge_length_m: float | None = None):
    """A virtual-bench log (BEM physics, bench noise) along a wall at a 2 cm gap, heading along it; with
    ``ball_m`` (a radius), a conducting ball meshed in the BEM's scene at the log's depth, mid-pass, 3 cm of water
    between it and the sensor on the tank's side; ``tank_grading``: of the physics' tank mesh (default the
    BEM's); ``wall_images``: each pose on its own tank mesh, the faces near it image planes (`bench-sim
    --wall-images`); ``edge_length_m``: the physics' sensor mesh; ``name``: of the log file. (log, the ball's
    centre or None)."""
    from click.testing import CliRunner

    from electrosense.meshes.sensor import save_sensor
    from electrosense.validation.cli import main

    lo, hi = tank.water_bounds_m
    y = hi[1] - sensor.radius_m - 0.02
    if hasattr(tank, "radius_m"):   # a chord of the cylinder 2 cm from its wall
        y = tank.radius_m - sensor.radius_m - 0.02 - 0.5 * sensor.length_m ** 2 / (4 * tank.radius_m)
    xe = np.sqrt(max((hi[1] - 0.03) ** 2 - y ** 2, 0.0)) - 0.5 * sensor.length_m if hasattr(tank, "radius_m") \
        else hi[0] - 0.5 * sensor.length_m - 0.03
    save_sensor(sensor, folder / "sensor.json")   # named in the log's meta line relative to the log's folder
    tank_text = (f"{tank.size_m[0]},{tank.size_m[1]},{tank.size_m[2]}" if not hasattr(tank, "radius_m") else None)
    if tank_text is None:
        raise NotImplementedError("the virtual bench has box tanks only")
    name = name or ("wall.csv" if ball_m is None else "ball.csv")
    if ball_m is not None:   # the part of the pass that sees the ball (a BEM pose with the ball meshed: 15 s)
        xe, n = min(xe, sensor.length_m + 0.05), max(11, n // 2)
    args = ["bench-sim", "-o", name, "--overwrite", "--sensor", "sensor.json",
            "--tank", tank_text, "--depth", str(tank.water_depth_m), "--sigma", "0.0354",
            "--path", f"line:{-xe},{y},{z},0:{xe},{y},{z},0:{n}", "--seed", str(seed)]
    if tank_grading is not None:
        args += ["--tank-grading", str(tank_grading)]
    if wall_images:
        args += ["--wall-images"]
    if edge_length_m is not None:
        args += ["--edge-length", str(edge_length_m)]
    centre = None
    if ball_m is not None:
        centre = [0.0, round(float(y - sensor.radius_m - 0.03 - ball_m), 4), float(z)]
        args += ["--effect", f"unmodelled_object=sphere,{centre[0]},{centre[1]},{centre[2]},{ball_m},conducting"]
    here = Path.cwd()
    try:
        os.chdir(folder)
        res = CliRunner().invoke(main, args)
    finally:
        os.chdir(here)
    if res.exit_code != 0:
        raise RuntimeError(res.output[-2000:])
    return folder / name, centre


def motion_prior_table(log, m, noise_rel) -> list[dict]:
    """The map's track error and bound under stiffer and looser motion priors, and each sample alone."""
    from electrosense.validation.bench.log import read_bench_log
    from electrosense.validation.diagnosis.observations import from_bench_logs
    from electrosense.validation.localisation.from_log import localise_observations
    from electrosense.validation.localisation.smoother import MotionModel

    obs = from_bench_logs([read_bench_log(log)])
    rows = []
    for q in (1e-6, 1e-4, 1e-2, None):
        motion = None if q is None else MotionModel(q, 10 * q)
        s = localise_observations(obs, m, noise_rel=noise_rel, motion=motion, with_psm=False)["map"]
        rows.append({"acceleration_psd_m2_per_s3": q, "position_rms_m": s["position_rms_m"],
                     "crb_position_rms_m": s["crb_position_rms_m"], "heading_rms_rad": s["heading_rms_rad"]})
    return rows


def _print_split(found: dict) -> None:
    """The line of :func:`error_split`'s figures, where it has them."""
    if "interpolation_rms" in found:
        print(f"    of it the coarse interpolant against its own BEM there {found['interpolation_rms']:.3%} RMS, "
              f"{found['interpolation_max']:.3%} max; the correction to the reference against the true one "
              f"{found['correction_rms']:.3%} RMS, {found['correction_max']:.3%} max")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--minutes", type=float, default=4.5, help="the build's wall-clock budget")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--test-poses", type=int, default=20)
    ap.add_argument("--near-wall-poses", type=int, default=8,
                    help=f"poses {1e3 * NEAR_WALL_GAP_M[0]:g}-{1e3 * NEAR_WALL_GAP_M[1]:g} mm from a wall, floor or "
                         "surface checked besides the test poses (0: none)")
    ap.add_argument("--corner-poses", type=int, default=8,
                    help=f"in a box, poses {1e3 * CORNER_GAP_M[0]:g}-{1e3 * CORNER_GAP_M[1]:g} mm from two walls at "
                         "once checked besides (0: none)")
    ap.add_argument("--log-poses", type=int, default=31)
    ap.add_argument("--cylinder", action="store_true", help="a cylindrical tank (no localisation: box bench only)")
    ap.add_argument("--band", type=float, default=0.0, help="a band of depths of this height (m) around z")
    ap.add_argument("--objects", type=int, default=0,
                    help="fixed objects in the tank (balls and poles at the sensor's depth; no localisation)")
    ap.add_argument("--skip-localisation", action="store_true")
    ap.add_argument("--sensor", default=None, help="a preset or sensor file instead of a random sensor")
    ap.add_argument("--tank", default=None, help="LX,LY,LZ (m, full) instead of a random box tank")
    ap.add_argument("--z", type=float, default=None, help="the depth instead of a random one")
    ap.add_argument("-o", "--out", default=None)
    args = ap.parse_args(argv)
    folder = Path(args.out or tempfile.mkdtemp(prefix="tank-map-study-"))
    folder.mkdir(parents=True, exist_ok=True)
    os.environ["ESENSE_CACHE_DIR"] = str(folder / "cache")   # an empty cache: everything from scratch
    from electrosense.validation.simulation.tank_map import build_tank_map, load_tank_map

    rng = np.random.default_rng(args.seed)
    sensor, tank, z = random_scene(rng, args.cylinder)
    if args.sensor:
        from electrosense.meshes.sensor import load_sensor

        sensor = load_sensor(args.sensor)
    if args.tank:
        from electrosense.meshes.tank import Tank

        tank = Tank(tuple(float(v) for v in args.tank.split(",")))
    z = z if args.z is None else args.z
    band = (z - args.band / 2, z + args.band / 2) if args.band else None
    objects = random_objects(np.random.default_rng([args.seed, 3]), sensor, tank, z, args.objects)
    print(f"sensor: {sensor.n_electrodes} electrodes, length {sensor.length_m:.3f} m, radius {sensor.radius_m:.4f} m, "
          f"emitter {sensor.emitter}; tank {tank}; z = {band or z} m; folder {folder}")
    for o in objects:
        print(f"  fixed object: {o}")
    results = {"sensor": sensor.to_dict(), "tank": repr(tank), "z_m": band or z,
               "objects": [repr(o) for o in objects]}
    # ---------------------------------------------------------------- build
    path = folder / "study.map.npz"
    w0, c0 = time.perf_counter(), _cpu_s()
    # the budget in CPU seconds (workers x minutes): on a busy machine the same map, in more wall-clock time
    m = build_tank_map(sensor, tank, band or z, path=path, objects=objects, max_seconds=6 * 60 * args.minutes,
                       max_cpu_seconds=args.workers * 60 * args.minutes, workers=args.workers,
                       progress=lambda s: print("  build:", s, flush=True))
    build_wall, build_cpu = time.perf_counter() - w0, _cpu_s() - c0
    t0 = time.perf_counter()
    for _ in range(5):
        m = load_tank_map(path)
    load_ms = 1e3 * (time.perf_counter() - t0) / 5
    est = m.history[-1]
    results["build"] = {"wall_s": build_wall, "cpu_s": build_cpu, "bem_poses": len(m.nodes), "load_ms": load_ms,
                        "reference_poses": int(len(m.ref_index)),
                        "estimated_rms": est["rms_error"], "estimated_max": est["max_error"]}
    save = lambda: (folder / "study.json").write_text(json.dumps(results, indent=1, default=float))  # noqa: E731
    save()
    # ---------------------------------------------------------------- accuracy
    print(f"BEM at {args.test_poses} random poses (tips 5 mm to 20 cm from a wall), on a tank mesh graded to them")
    P = test_poses(sensor, tank, z, rng, args.test_poses, band, objects=objects)
    errs = check_accuracy(m, sensor, tank, P, objects=objects)
    # the goal's BEM: each pose on its own tank mesh, the faces near it image planes (exact; a meshed wall beside
    # the sensor is 0.03-0.04 % RMS off them near the walls at the reference's grading and at 0.6x of it), as the
    # map's nodes; a map of format 9 and earlier reproduces the meshed walls, and is scored on one tank mesh
    headline = "same" if m.reference_images_m is not None else "other"
    err = errs[headline]
    err_est = m.estimated_error(P)
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    results["accuracy"] = {"rms": rms(err), "max": float(np.abs(err).max()), "estimated_rms": rms(err_est),
                           "against": headline,
                           "poses": P.tolist(), "errors": err.tolist(),
                           **{f"{k}_rms": rms(v) for k, v in errs.items()},
                           **{f"{k}_max": float(np.abs(v).max()) for k, v in errs.items()}}
    save()
    if args.near_wall_poses:
        print(f"BEM at {args.near_wall_poses} random poses {1e3 * NEAR_WALL_GAP_M[0]:g}-{1e3 * NEAR_WALL_GAP_M[1]:g} mm "
              "from a wall, each on its own tank mesh")
        results["near_wall"] = check_near_wall(m, sensor, tank, z, args.seed, args.near_wall_poses, band, objects)
        save()
    if objects and args.near_wall_poses:
        print(f"BEM at {args.near_wall_poses} random poses {1e3 * NEAR_WALL_GAP_M[0]:g}-{1e3 * NEAR_WALL_GAP_M[1]:g} mm "
              "from a fixed object, each on its own tank mesh")
        results["near_objects"] = check_near_objects(m, sensor, tank, z, args.seed, args.near_wall_poses, objects,
                                                     band)
        save()
    if args.corner_poses and not args.cylinder:
        print(f"BEM at {args.corner_poses} random poses {1e3 * CORNER_GAP_M[0]:g}-{1e3 * CORNER_GAP_M[1]:g} mm from "
              "two walls at once, each on its own tank mesh")
        results["corners"] = check_corners(m, sensor, tank, z, args.seed, args.corner_poses, band, objects)
        save()
    # ---------------------------------------------------------------- speed
    Q = test_poses(sensor, tank, z, rng, 2000, band, objects=objects)
    Q = np.repeat(Q, 50, axis=0)
    m.conductance(Q[:100], jacobian=True)
    t, c = time.perf_counter(), time.process_time()
    m.conductance(Q, jacobian=True)
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    results["speed"] = {"poses_per_s_jacobian_cpu": len(Q) / cpu, "poses_per_s_jacobian_wall": len(Q) / wall}
    if band is None and not objects:   # a grid would cross the objects, where the map refuses a pose
        run_rate, cmd_rate = sweep_speed(path, sensor, tank, z, folder)
        results["speed"].update({"sweep_poses_per_s": run_rate, "sweep_command_poses_per_s": cmd_rate})
    save()
    # ---------------------------------------------------------------- figure
    if band is None:
        print("the map and the PSM against the BEM from wall to wall")
        results["line"] = map_vs_psm_figure(m, sensor, tank, z, folder / "map_vs_psm.png", objects=objects)
    save()
    # ---------------------------------------------------------------- localisation
    if not (args.skip_localisation or args.cylinder or band or objects):
        from electrosense.validation.defaults import BENCH_CURRENT_NOISE_REL
        from electrosense.validation.localisation.from_log import localise_log

        # the bench's physics as near the converged BEM as the study affords, on other meshes than the map's: the
        # walls near the sensor exact (images; a meshed wall beside the sensor is 0.03-0.06 % off them, 0.028 % at
        # the pass's 2 cm on the BEM's default mesh, half the bench noise), the far faces on a tank mesh finer than
        # the map's reference (0.1 against 0.15), the sensor mesh 0.8x the map's reference; the pass on the
        # BEM's default meshes (one tank mesh for the path, every face meshed) beside it
        physics = {"wall_images": True, "tank_grading": 0.1, "edge_length_m": 0.8 * m.bem_options["edge_length_m"]}
        print(f"virtual-bench log of {args.log_poses} poses 2 cm from a wall (BEM physics: near walls exact, other "
              "meshes than the map's), then esense localise")
        log, _ = localisation_log(sensor, tank, z, folder, args.log_poses, args.seed, **physics)
        # the bound at the bench's specified noise (the virtual bench's): the noise measured on a short log is
        # inflated by the path's curvature, which would loosen the bound
        results["localise"] = localise_log(log, path, folder / "localise", noise_rel=BENCH_CURRENT_NOISE_REL,
                                           progress=lambda s: print(" ", s))
        results["localise"]["physics"] = physics
        results["localise_motion_priors"] = motion_prior_table(log, m, BENCH_CURRENT_NOISE_REL)
        measured = localise_log(log, path, folder / "localise_measured_noise", figure=False)
        results["localise_measured_noise"] = {k: measured[k] for k in ("noise_rel", "map", "psm")}
        print("the same pass with its BEM physics on the BEM's default meshes (one tank mesh, every face meshed)")
        log_default, _ = localisation_log(sensor, tank, z, folder, args.log_poses, args.seed, name="wall_default.csv")
        default = localise_log(log_default, path, folder / "localise_default_physics", noise_rel=BENCH_CURRENT_NOISE_REL,
                               figure=False, find_object=False)
        results["localise_default_physics"] = {k: default[k] for k in ("map", "psm")}
        save()
        print(f"virtual-bench log past a conducting ball of {1e3 * BALL_M:g} mm radius (BEM physics as above, the "
              "ball meshed), then esense localise --object-at")
        log, centre = localisation_log(sensor, tank, z, folder, args.log_poses, args.seed + 1, BALL_M, **physics)
        results["localise_object"] = localise_log(log, path, folder / "localise_object",
                                                  noise_rel=BENCH_CURRENT_NOISE_REL, true_object_m=centre,
                                                  progress=lambda s: print(" ", s))["object"]
    save()
    # ---------------------------------------------------------------- summary
    print("\nfigure                                                            measured   goal")
    b, a = results["build"], results["accuracy"]
    own = a.get("against") == "same"
    _line("map vs BEM at fresh poses" + (" (each on its own tank mesh, near faces images), RMS" if own else
                                         " (one tank mesh for all), RMS"), a["rms"], GOALS["rms"], "{:.3%}")
    _line("map vs BEM at fresh poses, max", a["max"], GOALS["max"], "{:.3%}")
    if own:
        print(f"  against one tank mesh graded to all of them, every face meshed (a fresh BEM as a user runs it "
              f"along a path): {a['other_rms']:.3%} RMS, {a['other_max']:.3%} max; the BEM itself between the two: "
              f"{a['bem_tank_rms']:.3%} RMS, {a['bem_tank_max']:.3%} max")
    elif "same_rms" in a:
        print(f"  against each pose on a tank mesh of its own, as the map's nodes (the interpolation alone): "
              f"{a['same_rms']:.3%} RMS, {a['same_max']:.3%} max; the BEM itself between the two: "
              f"{a['bem_tank_rms']:.3%} RMS, {a['bem_tank_max']:.3%} max")
    if "bem_sensor_rms" in a:
        print(f"  the reference BEM's own sensor-mesh error (against a 0.7x finer sensor mesh, {len(P[:4])} poses): "
              f"{a['bem_sensor_rms']:.3%} RMS, {a['bem_sensor_max']:.3%} max")
    if "bem_tank_grading_rms" in a:
        print(f"  its own tank-mesh error (each pose against a tank mesh graded 0.6x finer, {len(P[:4])} poses): "
              f"{a['bem_tank_grading_rms']:.3%} RMS, {a['bem_tank_grading_max']:.3%} max; the BEM's default tank "
              f"mesh against it: {a['bem_default_tank_rms']:.3%} RMS, {a['bem_default_tank_max']:.3%} max")
    print(f"  (the map's own estimate there: {a['estimated_rms']:.3%} RMS; at build end over all reachable poses "
          f"{b['estimated_rms']:.3%} RMS, {b['estimated_max']:.3%} max; {b['bem_poses']} BEM poses, "
          f"{b['reference_poses']} on the reference sensor mesh)")
    if "near_wall" in results:
        nw = results["near_wall"]
        print(f"  near the walls{' or objects' if objects else ''} ({len(nw['poses'])} poses {1e3 * min(nw['gaps_m']):.1f}-{1e3 * max(nw['gaps_m']):.1f} mm "
              f"from one, each on its own tank mesh): {nw['rms']:.3%} RMS, {nw['max']:.3%} max; the map's own "
              f"estimate there {nw['estimated_rms']:.3%} RMS")
        _print_split(nw)
        if "bem_sensor_rms" in nw:
            print(f"  the reference BEM's own sensor-mesh error at {len(nw['bem_sensor_errors'])} of them (against a "
                  f"0.7x finer sensor mesh): {nw['bem_sensor_rms']:.3%} RMS, {nw['bem_sensor_max']:.3%} max (the map "
                  "carries it)")
    if "near_objects" in results:
        no = results["near_objects"]
        print(f"  near the fixed objects ({len(no['poses'])} poses {1e3 * min(no['gaps_m']):.1f}-"
              f"{1e3 * max(no['gaps_m']):.1f} mm from one, each on its own tank mesh): {no['rms']:.3%} RMS, "
              f"{no['max']:.3%} max; the map's own estimate there {no['estimated_rms']:.3%} RMS")
        _print_split(no)
    if "corners" in results:
        co = results["corners"]
        print(f"  at the corners ({len(co['poses'])} poses {1e3 * CORNER_GAP_M[0]:g}-{1e3 * CORNER_GAP_M[1]:g} mm from "
              f"two walls, each on its own tank mesh): {co['rms']:.3%} RMS, {co['max']:.3%} max; the map's own "
              f"estimate there {co['estimated_rms']:.3%} RMS")
        _print_split(co)
    _line(f"build, wall s ({args.workers} workers, empty cache)", b["wall_s"], GOALS["build_s"], "{:.0f}")
    print(f"  build CPU s (all processes): {b['cpu_s']:.0f} (on {args.workers} free cores: about "
          f"{b['cpu_s'] / args.workers:.0f} s wall); loading the map: {b['load_ms']:.1f} ms")
    s = results["speed"]
    _line("poses/s with the pose Jacobian, one core (CPU time)", s["poses_per_s_jacobian_cpu"], GOALS["poses_per_s"],
          "{:.0f}", "above")
    if "sweep_poses_per_s" in s:
        _line("esense sweep --model map, poses/s (the run)", s["sweep_poses_per_s"], GOALS["poses_per_s"], "{:.0f}",
              "above")
        print(f"  the whole command, start-up and store included: {s['sweep_command_poses_per_s']:.0f} poses/s")
    if "localise" in results:
        lm, lp = results["localise"]["map"], results["localise"]["psm"]
        mm = lambda v: "none" if v is None else f"{1e3 * v:.3f} mm"  # noqa: E731
        if lm["crb_position_rms_m"]:
            _line("localisation, map: position RMS / its posterior Cramer-Rao bound", lm["position_rms_m"] /
                  lm["crb_position_rms_m"], GOALS["loc_over_crb"], "{:.2f}")
        _line("localisation, map: position RMS (m)", lm["position_rms_m"], GOALS["loc_rms_m"], "{:.2e}")
        print(f"  (physics: near walls exact, tank grading 0.1, sensor mesh 0.8x the map's; noise "
              f"{results['localise']['noise_rel']:.3%}, the bench's; motion prior "
              f"{results['localise']['motion_model']['acceleration_psd_m2_per_s3']:g} m^2/s^3)")
        print(f"  map: position {mm(lm['position_rms_m'])} RMS, bound {mm(lm['crb_position_rms_m'])} (each sample "
              f"alone: bound {mm(lm['crb_per_sample_position_rms_m'])}), heading {lm['heading_rms_rad']:.2e} rad RMS")
        print(f"  PSM: position {mm(lp['position_rms_m'])} RMS, bound {mm(lp['crb_position_rms_m'])} (each sample "
              f"alone: bound {mm(lp['crb_per_sample_position_rms_m'])}), heading {lp['heading_rms_rad']:.2e} rad RMS")
        print("  the map under other motion priors (acceleration PSD m^2/s^3; none: each sample alone):")
        for row in results["localise_motion_priors"]:
            print(f"    {str(row['acceleration_psd_m2_per_s3']):>8s}: position {mm(row['position_rms_m'])} RMS, "
                  f"bound {mm(row['crb_position_rms_m'])}")
        lmm = results["localise_measured_noise"]
        print(f"  with the noise measured on the log ({lmm['noise_rel']:.3%}): map {mm(lmm['map']['position_rms_m'])}"
              f" (bound {mm(lmm['map']['crb_position_rms_m'])}), PSM {mm(lmm['psm']['position_rms_m'])} (bound "
              f"{mm(lmm['psm']['crb_position_rms_m'])})")
        if "localise_default_physics" in results:
            lf = results["localise_default_physics"]
            print(f"  the pass's physics on the BEM's default meshes (one tank mesh, every face meshed): map "
                  f"{mm(lf['map']['position_rms_m'])} (bound {mm(lf['map']['crb_position_rms_m'])}, "
                  f"{lf['map']['position_rms_m'] / lf['map']['crb_position_rms_m']:.2f}x), PSM "
                  f"{mm(lf['psm']['position_rms_m'])}")
    if "localise_object" in results:
        from electrosense.validation.localisation.object_position import describe

        o = results["localise_object"]
        _line("object, map: position error / its Cramer-Rao bound", o["map"]["position_error_m"] /
              o["map"]["crb_position_rms_m"], GOALS["loc_over_crb"], "{:.2f}")
        _line("object, map: position error (m)", o["map"]["position_error_m"], GOALS["loc_rms_m"], "{:.2e}")
        print(f"  the ball at ({1e3 * o['true_centre_m'][0]:.1f}, {1e3 * o['true_centre_m'][1]:.1f}) mm, radius "
              f"{1e3 * BALL_M:g} mm")
        for name in ("map", "psm"):
            print(f"  {name}: {describe(o[name]) if name in o else o.get(name + '_left_out', 'not run')}")
        lo = results["localise"]["object"]["map"]
        print(f"  the pass without a ball, map: {describe(lo)}")
    print(f"wrote {folder / 'study.json'}")
    return results


if __name__ == "__main__":
    main()
