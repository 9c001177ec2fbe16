"""PSM speed: pose evaluations per second (paper8 / complete images) and calibration time, on one core.

Targets (issue): >= 100 000 poses/s for angels-4 with the paper's 8 images,
>= 10 000 poses/s with the complete image series, calibration < 5 s.
Run: ``python -m validation.studies.psm_speed [--poses N]``.
"""
from __future__ import annotations

import argparse
import os
import time

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402


def _random_poses(rng, n, half=0.3, z=0.0):
    poses = np.zeros((n, 4))
    poses[:, 0] = rng.uniform(-half, half, n)
    poses[:, 1] = rng.uniform(-half, half, n)
    poses[:, 2] = z
    poses[:, 3] = rng.uniform(-np.pi, np.pi, n)
    return poses


def _rate(fn, n_poses, repeats=3):
    fn()  # compile / warm
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return n_poses / best, best


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=200_000, help="poses per timed batch (paper8); complete uses a tenth")
    args = ap.parse_args(argv)

    from meshes.tank import Tank
    from psm import calibrate, conductance, receiver_current_jacobian
    from psm.paper import SIGMA_MEASURED_S_PER_M as sigma
    from psm.paper import paper_reference

    t = time.perf_counter()
    cal = calibrate(paper_reference(), symmetric=True)
    t_cal_first = time.perf_counter() - t
    t = time.perf_counter()
    calibrate(paper_reference(), symmetric=True)
    t_cal = time.perf_counter() - t
    model = cal.model
    tank = Tank((1.0, 1.0, 1.0))
    rng = np.random.default_rng(1)
    P8 = _random_poses(rng, args.poses)
    Pc = _random_poses(rng, max(args.poses // 10, 100))

    r8, _ = _rate(lambda: conductance(model, P8, sigma, tank, images="paper8"), len(P8))
    info = conductance(model, Pc, sigma, tank, images="complete").info
    rc_auto, _ = _rate(lambda: conductance(model, Pc, sigma, tank, images="complete"), len(Pc))
    rc_fixed, _ = _rate(lambda: conductance(model, Pc, sigma, tank, images="complete", image_shells=info["image_shells"]), len(Pc))
    rn, _ = _rate(lambda: conductance(model, P8, sigma, None), len(P8))
    Pj = Pc[:2000]
    rj8, _ = _rate(lambda: receiver_current_jacobian(model, Pj, sigma, tank, "paper8"), len(Pj))
    rjc, _ = _rate(lambda: receiver_current_jacobian(model, Pj, sigma, tank, "complete", image_shells=info["image_shells"]), len(Pj))

    print("PSM speed, angels-4 (calibrated on the paper's table), 1 m tank, one core")
    print(f"{'what':48s} {'measured':>14s} {'target':>12s}")
    print(f"{'poses/s, unbounded water':48s} {rn:14,.0f} {'-':>12s}")
    print(f"{'poses/s, paper8 images':48s} {r8:14,.0f} {'>= 100,000':>12s}")
    print(f"{'poses/s, complete series (auto shells, probes)':48s} {rc_auto:14,.0f} {'>= 10,000':>12s}")
    print(f"{'poses/s, complete series (shells fixed)':48s} {rc_fixed:14,.0f} {'>= 10,000':>12s}")
    print(f"{'  shells used / stated series error':48s} {info['image_shells']:>7d} / {info['image_series_error']:.1e}")
    print(f"{'Jacobian poses/s, paper8 (complex step)':48s} {rj8:14,.0f} {'-':>12s}")
    print(f"{'Jacobian poses/s, complete':48s} {rjc:14,.0f} {'-':>12s}")
    print(f"{'calibration s (first call, incl. warm-up)':48s} {t_cal_first:14.3f} {'< 5':>12s}")
    print(f"{'calibration s (again)':48s} {t_cal:14.3f} {'< 5':>12s}")
    return {"paper8": r8, "complete": rc_auto, "complete_fixed": rc_fixed, "calibration_s": t_cal_first}


if __name__ == "__main__":
    main()
