"""BEM speed and accuracy benchmark: our collocation BEM against the targets and against bempp-cl.

Figures (printed side by side with the targets of the BEM issue):

* ``angels-4`` in unbounded water at the default resolution, compiled
  kernels (target < 2 s), and in a fresh process (cached kernels; target < 20 s);
* ``angels-4`` and ``angels-2`` in the 1 m tank: first pose (target < 30 s;
  cold, and with the sensor block from the disk cache), each further pose of
  a sweep (target < 1 s), the paper's 161-pose sweep (target < 3 min, with
  ``--full``; otherwise 21 poses against a prorated target); peak memory
  (target < 6 GB);
* two spheres (radius 1 cm, centres 3 cm apart) against the exact series:
  error against the number of triangles and time, ours and bempp-cl's
  (Galerkin P0 single layer, dense LU), and the time each needs to reach
  0.3 % and 0.1 % (interpolated in log-log).

Run: ``python -m validation.studies.bem_speed [--full] [--no-bempp] [--levels 1 2 3 4]``.
bempp-cl is optional (``pip install bempp-cl``); its first operator compiles for about a minute.
"""
from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

from bem.closed_forms import two_sphere_resistance_ohm


def _two_sphere_mesh(subdivisions: int, a=0.01, d=0.03):
    import trimesh

    from meshes.labelled_mesh import LabelledMesh, concatenate

    s = trimesh.creation.icosphere(subdivisions)
    scale = a * (4 / 3 * np.pi / s.volume) ** (1 / 3)   # the polyhedron has the sphere's volume
    parts = [LabelledMesh(s.vertices * scale + [x, 0, 0], s.faces, np.full(len(s.faces), k), None, ("sensor",))
             for k, x in ((1, 0.0), (2, d))]
    return concatenate(parts)


def ours_two_spheres(levels):
    from bem.boundary_conditions import WaterBoundary
    from bem.solve import solve

    exact = two_sphere_resistance_ohm(0.01, 0.03)
    solve(WaterBoundary.from_meshes(_two_sphere_mesh(1)), 1.0)  # compile / load the cache
    rows = []
    for s in levels:
        mesh = _two_sphere_mesh(s)
        t0 = time.perf_counter()
        R = 1 / solve(WaterBoundary.from_meshes(mesh), 1.0).K_S[0, 0]
        rows.append((mesh.n_triangles, time.perf_counter() - t0, abs(R / exact - 1)))
    return rows


def bempp_two_spheres(levels):
    try:
        import bempp_cl.api as bempp
    except ImportError:
        return None
    import scipy.linalg

    exact = two_sphere_resistance_ohm(0.01, 0.03)
    rows = []
    t_compile = time.perf_counter()
    first = True
    for s in [levels[0]] + list(levels):
        mesh = _two_sphere_mesh(s)
        t0 = time.perf_counter()
        grid = bempp.Grid(mesh.vertices_m.T.copy(), mesh.faces.T.astype(np.uint32).copy())
        space = bempp.function_space(grid, "DP", 0)
        A = bempp.as_matrix(bempp.operators.boundary.laplace.single_layer(space, space, space).weak_form())
        areas = mesh.areas_m2
        b = np.column_stack([np.where(mesh.electrode == k, areas, 0.0) for k in (1, 2)])
        q = scipy.linalg.lu_solve(scipy.linalg.lu_factor(A), b)
        C = np.array([[np.sum(areas[mesh.electrode == m] * q[mesh.electrode == m, k]) for k in range(2)]
                      for m in (1, 2)])
        from bem.conductance import isolate

        R = 1 / isolate(C)[0, 0]
        if first:
            first = False
            compile_s = time.perf_counter() - t_compile
            continue
        rows.append((mesh.n_triangles, time.perf_counter() - t0, abs(R / exact - 1)))
    return rows, compile_s


def time_to_accuracy(rows, target):
    """Seconds to reach a relative error ``target``, interpolated in log-log between measured meshes."""
    n, t, e = (np.array(c, float) for c in zip(*rows))
    if e.min() > target:
        return np.nan
    k = int(np.argmax(e <= target))
    if k == 0:
        return t[0]
    f = np.log(target / e[k - 1]) / np.log(e[k] / e[k - 1])
    return float(np.exp(np.log(t[k - 1]) + f * (np.log(t[k]) - np.log(t[k - 1]))))


def sensor_timings(full: bool):
    from bem.solve import conductance_matrix
    from bem.sweep import PoseSweep
    from meshes import Scene, Tank, preset

    out = {}
    conductance_matrix(Scene(preset("angels-4")), 1.0)  # compile or load cached kernels
    t0 = time.perf_counter()
    g = conductance_matrix(Scene(preset("angels-4")), 1.0)
    out["angels-4 unbounded, default mesh (compiled)"] = (time.perf_counter() - t0, 2.0, f"{g.info['triangles']} triangles")
    code = ("import time; t=time.perf_counter(); from bem import conductance_matrix; from meshes import Scene, preset; "
            "conductance_matrix(Scene(preset('angels-4')), 1.0); print(time.perf_counter()-t)")
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    out["angels-4 unbounded, fresh process"] = (time.perf_counter() - t0, 20.0, "imports + cached kernels")
    tank = Tank((1.0, 1.0, 1.0))
    n_poses = 161 if full else 21
    x = np.linspace(-0.38, 0.38, n_poses)
    poses = np.column_stack([x, 0 * x, 0 * x, 0 * x])
    for name in ("angels-4", "angels-2"):
        with tempfile.TemporaryDirectory() as cache:
            t0 = time.perf_counter()
            sweep = PoseSweep(preset(name), tank, sigma_S_per_m=0.0354, block_cache=cache)
            sweep.conductance(poses[:1], check=False)
            first = time.perf_counter() - t0
            out[f"{name} in the 1 m tank, first pose"] = (first, 30.0, f"{len(sweep.env_tris)} tank + "
                                                          f"{sweep.sensor_mesh.n_triangles} sensor triangles")
            t0 = time.perf_counter()
            warm = PoseSweep(preset(name), tank, sigma_S_per_m=0.0354, block_cache=cache)
            warm.conductance(poses[:1], check=False)
            out[f"{name} in the 1 m tank, first pose, cached block"] = (time.perf_counter() - t0, 30.0,
                                                                        "sensor LU read from the disk cache")
        t0, c0 = time.perf_counter(), time.process_time()
        g = sweep.conductance(poses[1:], check=False)
        per_pose = (time.perf_counter() - t0) / (len(poses) - 1)
        cpu = (time.process_time() - c0) / (len(poses) - 1)
        ranks = g.info["coupling_rank"]
        out[f"{name} in the 1 m tank, each further pose"] = (per_pose, 1.0, f"CPU {cpu:.2f} s/pose (both cores); "
                                                             f"coupling rank {min(ranks)}-{max(ranks)}")
        out[f"{name}: {n_poses}-pose wall-to-wall sweep"] = (first + per_pose * (len(poses) - 1),
                                                            180.0 if full else 180.0 * n_poses / 161,
                                                            "first pose (cold) included")
    peak_gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    out["peak memory (GB)"] = (peak_gb, 6.0, "resident set, this process")
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(prog="bem_speed", description=__doc__.splitlines()[0])
    parser.add_argument("--full", action="store_true", help="the full 161-pose sweep")
    parser.add_argument("--no-bempp", action="store_true", help="skip bempp-cl")
    parser.add_argument("--levels", type=int, nargs="+", default=[1, 2, 3, 4], help="icosphere subdivisions")
    parser.add_argument("--skip-sensor", action="store_true", help="only the two-sphere comparison")
    args = parser.parse_args(argv)
    if not args.skip_sensor:
        print("figure                                           ours        target   note")
        for name, (value, target, note) in sensor_timings(args.full).items():
            flag = "ok" if value <= target else "MISSED"
            print(f"{name:48s} {value:8.2f}   < {target:6.1f}   {flag:6s} {note}")
    print("\ntwo spheres a = 1 cm, d = 3 cm against the exact series (R = %.5f ohm at sigma = 1)"
          % two_sphere_resistance_ohm(0.01, 0.03))
    ours = ours_two_spheres(args.levels)
    theirs = None if args.no_bempp else bempp_two_spheres(args.levels)
    print(f"{'triangles':>10s} | {'ours s':>8s} {'ours err':>9s} | {'bempp s':>8s} {'bempp err':>9s}")
    for k, (n, t, e) in enumerate(ours):
        b = theirs[0][k] if theirs else None
        print(f"{n:10d} | {t:8.2f} {e:9.2e} | " + (f"{b[1]:8.2f} {b[2]:9.2e}" if b else "     n/a       n/a"))
    for target in (3e-3, 1e-3):
        t_ours = time_to_accuracy(ours, target)
        t_theirs = time_to_accuracy(theirs[0], target) if theirs else np.nan
        print(f"time to {100 * target:.1f} %: ours {t_ours:.2f} s, bempp-cl {t_theirs:.2f} s"
              + (f" ({t_theirs / t_ours:.1f}x)" if np.isfinite(t_theirs) and np.isfinite(t_ours) else ""))
    if theirs:
        print(f"bempp-cl first operator (compilation included): {theirs[1]:.1f} s")


if __name__ == "__main__":
    main()
