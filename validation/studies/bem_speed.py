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
  0.3 % and 0.1 % (interpolated in log-log);
* the sensor (``angels-4`` in unbounded water, sigma = 1 S/m) against its
  converged S, on the same meshes for both: ``mesh_sensor`` with edge length
  ``h0 / d`` and grading ``1 + 0.15 / d`` for refinement factors ``d``; the
  largest relative error over the entries of S against the number of
  triangles and time, ours and bempp-cl's (the mixed problem in Galerkin P0,
  dense LU: :mod:`electrosense.validation.studies.bempp_sensor`), and the time each needs
  to reach 0.3 % and 0.1 %. bempp-cl stops at ``--bempp-max-triangles``
  (its dense matrices take some 7 GB at 16 000 triangles).

Run: ``python -m electrosense.validation.studies.bem_speed [--full] [--no-bempp] [--levels 1 2 3 4]
[--sensor-levels 0.5 0.7 1 1.41] [--bempp-max-triangles 20000] [--no-sensor-comparison]``
(``--skip-sensor``: without the sensor timings against the targets). The
default sensor levels take about a minute for ours and 3 minutes for bempp-cl
on two cores.
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

from electrosense.bem.closed_forms import two_sphere_resistance_ohm


def _two_sphere_mesh(subdivisions: int, a=0.01, d=0.03):
    import trimesh

    from electrosense.meshes.labelled_mesh import LabelledMesh, concatenate

    s = trimesh.creation.icosphere(subdivisions)
    scale = a * (4 / 3 * np.pi / s.volume) ** (1 / 3)   # the polyhedron has the sphere's volume
    parts = [LabelledMesh(s.vertices * scale + [x, 0, 0], s.faces, np.full(len(s.faces), k), None, ("sensor",))
             for k, x in ((1, 0.0), (2, d))]
    return concatenate(parts)


def ours_two_spheres(levels):
    from electrosense.bem.boundary_conditions import WaterBoundary
    from electrosense.bem.solve import solve

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
        from electrosense.bem.conductance import isolate

        R = 1 / isolate(C)[0, 0]
        if first:
            first = False
            compile_s = time.perf_counter() - t_compile
            continue
        rows.append((mesh.n_triangles, time.perf_counter() - t0, abs(R / exact - 1)))
    return rows, compile_s


#: refinement factors d of the sensor meshes (edge length h0 / d, grading 1 + 0.15 / d)
SENSOR_LEVELS = (0.5, 0.7, 1.0, 1.41)


def sensor_mesh_at(sensor, d: float):
    """The sensor's mesh at refinement factor ``d``: edge length ``h0 / d``, grading ``1 + 0.15 / d``.

    Parameters
    ----------
    sensor : SensorDescription
    d : float
        Refinement factor; ``d = 1`` is the default edge length ``h0`` (with grading 1.15).

    Returns
    -------
    LabelledMesh
    """
    from electrosense.meshes.sensor_mesh import default_edge_length_m, mesh_sensor

    return mesh_sensor(sensor, edge_length_m=default_edge_length_m(sensor) / d, grading=1 + 0.15 / d)


def max_relative_error(S, reference_S) -> float:
    """``max |S_ij / reference_ij - 1|`` over the entries of S."""
    return float(np.max(np.abs(np.asarray(S) / np.asarray(reference_S) - 1)))


def _sensor(sensor):
    """A SensorDescription from a preset name or itself."""
    from electrosense.meshes import preset

    return preset(sensor) if isinstance(sensor, str) else sensor


def ours_sensor(levels, reference_S, sensor="angels-4", sigma_S_per_m: float = 1.0):
    """Our BEM on the sensor in unbounded water, at each refinement factor of ``levels``.

    Parameters
    ----------
    levels : sequence of float
        Refinement factors ``d`` (see :func:`sensor_mesh_at`).
    reference_S : (n-1, n-1) array
        The converged S (siemens) at ``sigma_S_per_m``.
    sensor : str or SensorDescription
        Preset name or sensor; ``reference_S`` must be its converged S.
    sigma_S_per_m : float

    Returns
    -------
    list of (triangles, seconds, error, corrected seconds, corrected error)
        ``error``: :func:`max_relative_error` of S of the surface solution itself (full collocation);
        ``seconds``: boundary, assembly and solve. ``corrected``: with the edge correction of
        :mod:`electrosense.bem.edge_correction` added (what ``conductance_matrix`` returns by default; in unbounded
        water that is the ring elements' K, so its time adds theirs, computed afresh).
    """
    from electrosense.bem import edge_correction
    from electrosense.bem.boundary_conditions import WaterBoundary
    from electrosense.bem.conductance import S_from_K
    from electrosense.bem.solve import solve

    s = _sensor(sensor)
    solve(WaterBoundary.from_meshes(sensor_mesh_at(s, min(levels)), emitter=s.emitter), sigma_S_per_m)  # kernels
    rows = []
    for d in levels:
        mesh = sensor_mesh_at(s, d)
        t0 = time.perf_counter()
        K = solve(WaterBoundary.from_meshes(mesh, emitter=s.emitter), sigma_S_per_m).K_S
        seconds = time.perf_counter() - t0
        edge_correction.clear_cache()
        t0 = time.perf_counter()
        dK = edge_correction.free_space_correction(s, sigma_S_per_m, None, mesh, surface_K_S=None)
        corrected_seconds = seconds + time.perf_counter() - t0
        rows.append((mesh.n_triangles, seconds, max_relative_error(S_from_K(K, s.emitter), reference_S),
                     corrected_seconds, max_relative_error(S_from_K(K + dK, s.emitter), reference_S)))
    return rows


def bempp_sensor(levels, reference_S, sensor="angels-4", sigma_S_per_m: float = 1.0,
                 max_triangles: int = 20000):
    """bempp-cl on the sensor (the mixed problem in Galerkin P0, dense LU) at each refinement factor.

    The first level is solved twice: the first time includes the compilation
    of bempp-cl's kernels (in a process that has already assembled bempp-cl's
    single layer, the double layer's mostly) and is reported apart.

    Parameters
    ----------
    levels : sequence of float
        Refinement factors ``d`` (see :func:`sensor_mesh_at`); meshes of more
        than ``max_triangles`` triangles are skipped.
    reference_S : (n-1, n-1) array
        The converged S (siemens) at ``sigma_S_per_m``.
    sensor : str or SensorDescription
        Preset name or sensor; ``reference_S`` must be its converged S.
    sigma_S_per_m : float
    max_triangles : int
        The dense matrices take 3 x 8 bytes x triangles^2.

    Returns
    -------
    (rows, compile_s) or None
        ``rows``: (triangles, seconds, error) as for :func:`ours_sensor`;
        ``compile_s``: the first solve, compilation included. None without bempp-cl.
    """
    from electrosense.validation.studies.bempp_sensor import bempp_available, bempp_conductance

    if not bempp_available():
        return None
    s = _sensor(sensor)
    meshes = [m for m in (sensor_mesh_at(s, d) for d in levels) if m.n_triangles <= max_triangles]
    if not meshes:
        return [], np.nan
    t0 = time.perf_counter()
    bempp_conductance(meshes[0], sigma_S_per_m, s.emitter)
    compile_s = time.perf_counter() - t0
    rows = []
    for mesh in meshes:
        t0 = time.perf_counter()
        S = bempp_conductance(mesh, sigma_S_per_m, s.emitter).S_S
        rows.append((mesh.n_triangles, time.perf_counter() - t0, max_relative_error(S, reference_S)))
    return rows, compile_s


def print_sensor_comparison(levels, reference_S, with_bempp: bool = True, bempp_max_triangles: int = 20000,
                            sensor="angels-4", sigma_S_per_m: float = 1.0):
    """Print ours and bempp-cl's error and time side by side on the sensor's meshes, and the time to 0.3 % and 0.1 %.

    Parameters
    ----------
    levels : sequence of float
        Refinement factors ``d`` (see :func:`sensor_mesh_at`).
    reference_S : (n-1, n-1) array
        The converged S (siemens) at ``sigma_S_per_m``.
    with_bempp : bool
        Run bempp-cl too (skipped with a note when it is not installed).
    bempp_max_triangles : int
        bempp-cl's largest mesh.
    sensor : str or SensorDescription
        Preset name or sensor; ``reference_S`` must be its converged S.
    sigma_S_per_m : float

    Returns
    -------
    ours, theirs
        As returned by :func:`ours_sensor` and :func:`bempp_sensor`.
    """
    s = _sensor(sensor)
    print(f"\n{s.name} (radius {1e3 * s.radius_m:.3f} mm) in unbounded water (sigma = {sigma_S_per_m:g} S/m) "
          f"against its converged S\n(max relative error over the entries of S; the same meshes for both: "
          f"edge length h0/d, grading 1 + 0.15/d)")
    ours = ours_sensor(levels, reference_S, s, sigma_S_per_m)
    theirs = bempp_sensor(levels, reference_S, s, sigma_S_per_m, bempp_max_triangles) if with_bempp else None
    if with_bempp and theirs is None:
        print("(bempp-cl is not installed: ours only)")
    by_n = {n: (t, e) for n, t, e in theirs[0]} if theirs else {}
    print(f"{'d':>5s} {'triangles':>10s} | {'ours s':>8s} {'ours err':>9s} | {'corrected s':>11s} {'err':>9s} | "
          f"{'bempp s':>8s} {'bempp err':>9s}")
    for d, (n, t, e, tc, ec) in zip(levels, ours):
        b = by_n.get(n)
        print(f"{d:5.2f} {n:10d} | {t:8.2f} {e:9.2e} | {tc:11.2f} {ec:9.2e} | "
              + (f"{b[0]:8.2f} {b[1]:9.2e}" if b else "     n/a       n/a"))

    def seconds(t):
        return f"{t:.2f} s" if np.isfinite(t) else "not reached"

    for target in (3e-3, 1e-3):
        t_ours = time_to_accuracy([r[:3] for r in ours], target)
        t_corrected = time_to_accuracy([(r[0], r[3], r[4]) for r in ours], target)
        t_theirs = time_to_accuracy(theirs[0], target) if theirs and theirs[0] else np.nan
        print(f"time to {100 * target:.1f} %: ours {seconds(t_ours)} (surface solution alone), "
              f"{seconds(t_corrected)} (with the edge correction, the default), "
              f"bempp-cl {seconds(t_theirs) if theirs else 'n/a'}"
              + (f" (bempp-cl / ours corrected = {t_theirs / t_corrected:.2g})"
                 if np.isfinite(t_theirs) and np.isfinite(t_corrected) else ""))
    if theirs:
        print(f"bempp-cl first sensor solve (compilation included): {theirs[1]:.1f} s")
    return ours, theirs


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
    from electrosense.bem.solve import conductance_matrix
    from electrosense.bem.sweep import PoseSweep
    from electrosense.meshes import Scene, Tank, preset

    out = {}
    from electrosense.bem.edge_correction import clear_cache

    conductance_matrix(Scene(preset("angels-4")), 1.0)  # compile or load cached kernels
    clear_cache()                                        # time the edge correction too
    t0 = time.perf_counter()
    g = conductance_matrix(Scene(preset("angels-4")), 1.0)
    out["angels-4 unbounded, default mesh (compiled)"] = (time.perf_counter() - t0, 2.0, f"{g.info['triangles']} triangles")
    code = ("import time; t=time.perf_counter(); from electrosense.bem import conductance_matrix; from electrosense.meshes import Scene, preset; "
            "conductance_matrix(Scene(preset('angels-4')), 1.0); print(time.perf_counter()-t)")
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
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
    parser.add_argument("--skip-sensor", action="store_true", help="skip the sensor timings against the targets")
    parser.add_argument("--no-sensor-comparison", action="store_true",
                        help="skip the sensor's error and time against its converged S (ours and bempp-cl)")
    parser.add_argument("--sensor-levels", type=float, nargs="+", default=list(SENSOR_LEVELS),
                        help="refinement factors d of the sensor meshes (edge length h0/d, grading 1 + 0.15/d)")
    parser.add_argument("--bempp-max-triangles", type=int, default=20000,
                        help="largest sensor mesh for bempp-cl (dense: 3 x 8 bytes x triangles^2)")
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
    if not args.no_sensor_comparison:
        from electrosense.bem.meridian import converged_conductance
        from electrosense.meshes import preset

        reference = converged_conductance(preset("angels-4"), 1.0)
        print(f"\nreference: converged S of angels-4 by ring elements on the meridian (bem.meridian, "
              f"{reference.info['elements']} elements, Richardson, finest within "
              f"{100 * reference.info['finest_departure']:.4f} %)")
        print_sensor_comparison(args.sensor_levels, reference.S_S, with_bempp=not args.no_bempp,
                                bempp_max_triangles=args.bempp_max_triangles)


if __name__ == "__main__":
    main()
