"""PSM speed: pose evaluations per second (paper8 / complete images) and calibration time, on one core.

Targets (issue): >= 100 000 poses/s for angels-4 with the paper's 8 images,
>= 10 000 poses/s with the complete image series, calibration < 5 s.
Run: ``python -m electrosense.validation.studies.psm_speed [--poses N]``.
"""
from __future__ import annotations

import argparse
import time

from electrosense.validation.simulation.workers import one_thread_environment

one_thread_environment()

import numpy as np  # noqa: E402


def _random_poses(rng, n, half=0.3, z=0.0):
    poses = np.zeros((n, 4))
    poses[:, 0] = rng.uniform(-half, half, n)
    poses[:, 1] = rng.uniform(-half, half, n)
    poses[:, 2] = z
    poses[:, 3] = rng.uniform(-np.pi, np.pi, n)
    return poses


def _rate(fn, n_poses, repeats=3):
    """Poses per second: (wall clock, CPU time of this process); the best of ``repeats``.

    On a shared machine the wall clock counts the time other processes hold
    the core; the CPU time is what one core of our own costs.
    """
    fn()  # compile / warm
    wall = cpu = np.inf
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        fn()
        wall = min(wall, time.perf_counter() - t)
        cpu = min(cpu, time.process_time() - c)
    return n_poses / wall, n_poses / cpu


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=200_000, help="poses per timed batch (paper8); complete uses a tenth")
    args = ap.parse_args(argv)

    from electrosense.meshes.tank import Tank
    from electrosense.psm import calibrate, conductance, receiver_current_jacobian
    from electrosense.psm.paper import SIGMA_MEASURED_S_PER_M as sigma
    from electrosense.psm.paper import paper_reference

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

    info = conductance(model, Pc, sigma, tank, images="complete").info
    Pj = Pc[:2000]
    rows = [
        ("poses/s, unbounded water", lambda: conductance(model, P8, sigma, None), len(P8), "-"),
        ("poses/s, paper8 images", lambda: conductance(model, P8, sigma, tank, images="paper8"), len(P8), ">= 100,000"),
        ("poses/s, complete series (auto shells)", lambda: conductance(model, Pc, sigma, tank, images="complete"),
         len(Pc), ">= 10,000"),
        ("poses/s, complete series (shells fixed)",
         lambda: conductance(model, Pc, sigma, tank, images="complete", image_shells=info["image_shells"]), len(Pc), ">= 10,000"),
        ("Jacobian poses/s, paper8 (analytic)", lambda: receiver_current_jacobian(model, Pj, sigma, tank, "paper8"),
         len(Pj), "-"),
        ("Jacobian poses/s, complete (analytic)",
         lambda: receiver_current_jacobian(model, Pj, sigma, tank, "complete", image_shells=info["image_shells"]), len(Pj), "-"),
        ("Jacobian poses/s, complete (complex step)",
         lambda: receiver_current_jacobian(model, Pj, sigma, tank, "complete", image_shells=info["image_shells"],
                                           method="complex-step"), len(Pj), "-"),
    ]
    print("PSM speed, angels-4 (calibrated on the paper's table), 1 m tank, one core (numba kernel, one thread)")
    print(f"{'what':44s} {'wall clock':>12s} {'CPU time':>12s} {'target':>12s}")
    out = {}
    for label, fn, n, target in rows:
        wall, cpu = _rate(fn, n)
        out[label] = (wall, cpu)
        print(f"{label:44s} {wall:12,.0f} {cpu:12,.0f} {target:>12s}")
    print(f"{'  complete: shells used / stated series error':44s} {info['image_shells']:>12d} {info['image_series_error']:12.1e}")
    print(f"{'calibration s (first call, incl. warm-up)':44s} {t_cal_first:12.3f} {'':>12s} {'< 5':>12s}")
    print(f"{'calibration s (again)':44s} {t_cal:12.3f} {'':>12s} {'< 5':>12s}")
    out["calibration_s"] = t_cal_first
    return out


if __name__ == "__main__":
    main()
