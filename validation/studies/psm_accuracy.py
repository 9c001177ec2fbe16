"""PSM accuracy against the BEM: wall-to-wall trajectory at y = 0 in the 1 m tank, complete vs paper8 images.

The PSM is calibrated on our own free-space BEM of the sensor (angels-2:
equal radii, length fixed to 20 cm; angels-4: the paper's symmetric
layout), then every receiver current along the trajectory is compared with
the BEM in the closed tank (walls, floor and free surface insulating).
The paper's figures are 0.22 % (angels-2) and 0.97 % (angels-4) mean
relative error. Besides the mean we print where along the path each image
variant departs from the BEM (first |x| from the middle at which the
error exceeds the paper's figure) and the error of the tank's effect alone
(currents relative to the mid-tank pose, which removes the calibration's
constant offset).

A third row, ``wall-fit``, goes beyond the paper: the same symmetric fit
with the BEM at two tank poses (x nearest -+0.33 m) added to the least
squares (``calibrate(..., tank_reference=...)``), which places the spheres
along the axis from the walls' effect instead of fixing the length.

Run: ``python -m electrosense.validation.studies.psm_accuracy [--steps 39] [--edge-length M]``.
Needs ``electrosense.bem.conductance_matrix`` and ``electrosense.bem.PoseSweep`` (docs/architecture.md).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from electrosense.validation.defaults import NOMINAL_SIGMA_S_PER_M

PAPER_TARGET = {"angels-2": 0.0022, "angels-4": 0.0097}


def _trajectory(sensor, model, tank, steps, margin_m=0.01):
    """x from wall to wall at y = z = 0, yaw 0, as far as both the real sensor and the PSM's spheres fit."""
    half_x = 0.5 * tank.size_m[0]
    reach_real = 0.5 * sensor.length_m + margin_m
    reach_psm = float(np.max(np.abs(model.centres_m[:, 0]) + model.radii_m)) + 1e-3
    x_max = half_x - max(reach_real, reach_psm)
    poses = np.zeros((steps, 4))
    poses[:, 0] = np.linspace(-x_max, x_max, steps)
    return poses


def _departure(x, err, threshold):
    """Smallest |x| (from the middle outwards) at which the error exceeds ``threshold`` on each side."""
    out = []
    for side in (x < 0, x > 0):
        xs, es = np.abs(x[side]), err[side]
        over = xs[es > threshold]
        out.append(float(over.min()) if over.size else None)
    return out


def _fmt(v):
    return "never" if v is None else f"|x| >= {v:.3f} m"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sensors", default="angels-2,angels-4", help="comma-separated presets")
    ap.add_argument("--steps", type=int, default=39, help="poses along the trajectory")
    ap.add_argument("--edge-length", type=float, default=None, help="BEM edge length (m); default: the mesher's")
    ap.add_argument("--sigma", type=float, default=NOMINAL_SIGMA_S_PER_M, help="water conductivity (S/m)")
    ap.add_argument("--interior", type=float, default=0.35,
                    help="also average over |x| <= this (m): the real tip at least 5 cm from the walls")
    args = ap.parse_args(argv)

    try:
        from electrosense.bem import conductance_matrix
    except ImportError as exc:
        print(f"psm_accuracy: the BEM is not available yet ({exc}); nothing to compare against.")
        return None
    try:
        from electrosense.bem import PoseSweep
    except ImportError:
        PoseSweep = None

    from electrosense.meshes.scene import Scene
    from electrosense.meshes.sensor import preset
    from electrosense.meshes.tank import Tank
    from electrosense.psm import calibrate, conductance

    tank = Tank((1.0, 1.0, 1.0))
    results = {}
    for name in args.sensors.split(","):
        sensor = preset(name)
        t0 = time.perf_counter()
        ref = conductance_matrix(Scene(sensor), args.sigma, edge_length_m=args.edge_length)
        t_ref = time.perf_counter() - t0
        fix = 0.2 if sensor.n_electrodes == 2 else None
        cal = calibrate(ref, symmetric=True, fix_length_m=fix, sensor=sensor)
        poses = _trajectory(sensor, cal.model, tank, args.steps)
        t0 = time.perf_counter()
        if PoseSweep is not None:
            sweep = PoseSweep(sensor, tank=tank, sigma_S_per_m=args.sigma, edge_length_m=args.edge_length)
            C_bem = sweep.conductance(poses)
        else:  # one full solve per pose
            from electrosense.meshes.pose import Pose

            C_bem = [conductance_matrix(Scene(sensor, Pose(*p), tank), args.sigma, edge_length_m=args.edge_length) for p in poses]
            from electrosense.bem.conductance import ConductanceMatrix

            C_bem = ConductanceMatrix(np.stack([c.K_S for c in C_bem]), sensor.emitter, args.sigma)
        I_bem = C_bem.receiver_currents_A()
        t_bem = time.perf_counter() - t0
        # beyond the paper: the same fit plus the BEM at two tank poses (nearest x = -+0.33 m), which places
        # the spheres along the axis from the walls' effect (calibrate(..., tank_reference=...))
        pick = [int(np.argmin(np.abs(poses[:, 0] - x))) for x in (-0.33, 0.33)]
        wall_cal = calibrate(ref, symmetric=True, sensor=sensor, tank_reference=(tank, poses[pick], C_bem[pick]))
        if np.abs(_trajectory(sensor, wall_cal.model, tank, args.steps)[0, 0]) < np.abs(poses[0, 0]) - 1e-12:
            wall_cal = None  # its spheres would leave the water at the ends of this trajectory
        mid = int(np.argmin(np.abs(poses[:, 0])))
        inner = np.abs(poses[:, 0]) <= args.interior + 1e-12
        # receiver 1 of a mirror-symmetric sensor collects the same current at x and -x: the BEM's own noise
        mirror = float(np.max(np.abs(I_bem[:, 0] - I_bem[::-1, 0]) / np.abs(I_bem[:, 0])))
        print(f"\n== {name}: free-space BEM {t_ref:.1f} s, tank BEM {t_bem:.1f} s for {len(poses)} poses, "
              f"x = {poses[0, 0]:.3f} .. {poses[-1, 0]:.3f} m")
        print(cal.summary())
        target = PAPER_TARGET.get(name)
        print(f"BEM mirror asymmetry of receiver 1 (its discretisation noise): {mirror * 100:.3f} %")
        print(f"{'images':10s} {'mean rel err':>13s} {'mean |x|<=' + format(args.interior, '.2f'):>15s} {'max rel err':>12s} "
              f"{'tank effect':>12s} {'paper':>8s}   departs beyond the paper's figure (x<0 | x>0)")
        rows = {}
        variants = [("complete", cal.model, "complete"), ("paper8", cal.model, "paper8")]
        if wall_cal is not None:
            variants.append(("wall-fit", wall_cal.model, "complete"))
        for images, model_v, kind in variants:
            C = conductance(model_v, poses, args.sigma, tank, images=kind)
            I = C.receiver_currents_A()
            rel = np.abs(I - I_bem) / np.abs(I_bem)
            effect = np.abs(I / I[mid] - I_bem / I_bem[mid])  # tank effect relative to mid-tank
            per_pose = rel.max(axis=1)
            dep = _departure(poses[:, 0], per_pose, target if target else np.inf)
            rows[images] = {"mean": float(rel.mean()), "mean_interior": float(rel[inner].mean()), "max": float(rel.max()),
                            "effect_max": float(effect.max()), "departs": dep, "bem_mirror_asymmetry": mirror, "rel": rel}
            print(f"{images:10s} {rel.mean() * 100:12.3f}% {rel[inner].mean() * 100:14.3f}% {rel.max() * 100:11.3f}% "
                  f"{effect.max() * 100:11.3f}% "
                  f"{(target or np.nan) * 100:7.2f}%   {_fmt(dep[0])} | {_fmt(dep[1])}")
        if wall_cal is not None:
            print(f"wall-fit: complete images, calibrated on the free-space BEM plus the BEM at x = "
                  f"{poses[pick[0], 0]:+.3f} and {poses[pick[1], 0]:+.3f} m (part of this trajectory):")
            print("  " + wall_cal.summary().replace("\n", "\n  "))
        print("x (m)     " + " ".join(f"{k:>9s}" for k in rows) + "   (max rel. error over receivers, %)")
        for k in range(0, len(poses), max(1, len(poses) // 13)):
            print(f"{poses[k, 0]:+.3f}    " + " ".join(f"{rows[v]['rel'][k].max() * 100:9.3f}" for v in rows))
        results[name] = {k: {kk: vv for kk, vv in v.items() if kk != "rel"} for k, v in rows.items()}
    return results


if __name__ == "__main__":
    main()
