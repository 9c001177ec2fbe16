"""BEM against the paper: fit of the angels presets, the 1 m tank sweep, mesh convergence.

1. ``angels-4``: the unknown dimensions (radius, cap extent, ring width, ring
   centre; 20 cm length) are fitted by least squares so that the free-space
   BEM ``S`` matches the paper's S_BEM table entry by entry.
2. ``angels-2`` with the same body: its free-space conductance gives the
   PSM equivalent radius ``a`` from ``S = 4 pi sigma / (2/a - 2/L)``, L = 20 cm
   (paper: a ~ 0.71 cm).
3. ``angels-2`` in the 1 m tank at 0.0354 S/m, wall to wall at y = 0: the
   resistance U/I (paper: ~600 ohm mid-tank, rising towards the walls).
4. Mesh convergence: the conductance matrix at the default meshes against
   mesh-converged references: in free space the ring-element BEM on the
   meridian (bem.meridian, Richardson, order 2), without and with the edge
   correction; mid-tank and with the tip 1 cm from a wall, Richardson over
   refined tank meshes and a refined sensor mesh.

5. Free-space convergence of the surface BEM far past the default mesh (h0/2,
   h0/4, h0/8, the edge grading refined with it, axisymmetric reduction),
   against the ring elements' converged value.

6. The tank mesh near a wall: the default against a tank mesh whose edge is at
   most 0.125x its distance from the sensor's surface, tips 5, 20 and 100 mm
   from the end wall (``--wall``).

Run: ``esense study bem_paper [--fit] [--sweep] [--convergence] [--fine-reference] [--wall]``
(no flag: all of them; ``--fit`` takes several minutes).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from electrosense.psm.paper import SIGMA_MEASURED_S_PER_M

#: the paper's free-space S_BEM of the 4-electrode sensor, in units of sigma x cm (gamma/100 x ...)
PAPER_S_BEM_SIGMA_CM = np.array([[7.1970, -2.7412, -2.2540], [-2.7412, 7.6781, -2.6875], [-2.2540, -2.6875, 7.6781]])
PAPER_A2_RADIUS_M = 0.0071
LENGTH_M = 0.20
SIGMA_PAPER = SIGMA_MEASURED_S_PER_M


def angels(n: int, radius_m, cap_extent_m, ring_width_m, ring_centre_m):
    """An angels-n sensor with the given dimensions (20 cm long)."""
    from electrosense.meshes.sensor import Electrode, SensorDescription

    half = LENGTH_M / 2
    electrodes = [Electrode("cap", half - cap_extent_m, half)]
    if n == 4:
        w, xc = ring_width_m, ring_centre_m
        electrodes += [Electrode("ring", xc - w / 2, xc + w / 2), Electrode("ring", -xc - w / 2, -xc + w / 2)]
    electrodes.append(Electrode("cap", -half, -half + cap_extent_m))
    return SensorDescription(f"angels-{n}", radius_m, LENGTH_M, tuple(electrodes))


def free_space_S_sigma_cm(sensor, edge_length_m=None, **mesh_options) -> np.ndarray:
    """Free-space S of a sensor in units of sigma x cm (sigma = 1 S/m, S in 1e-2 S): the surface BEM at
    the default mesh with its edge correction (:mod:`electrosense.bem.edge_correction`)."""
    from electrosense.bem.solve import conductance_matrix
    from electrosense.meshes.scene import Scene

    return conductance_matrix(Scene(sensor), 1.0, edge_length_m=edge_length_m, **mesh_options).S_S * 100.0


def meridian_S_sigma_cm(sensor) -> np.ndarray:
    """Free-space S (sigma x cm) by ring elements on the meridian (:mod:`electrosense.bem.meridian`), ~1e-4 of converged."""
    from electrosense.bem.edge_correction import MERIDIAN_GRADING
    from electrosense.bem.meridian import meridian_conductance, mesh_meridian

    return meridian_conductance(sensor, 1.0, mesh=mesh_meridian(sensor, grading=MERIDIAN_GRADING)).S_S * 100.0


def equivalent_radius_m(S_two_electrode: float, sigma=1.0, length_m=LENGTH_M) -> float:
    """PSM radius a of two equal spheres L apart with the same conductance: S = 4 pi sigma / (2/a - 2/L)."""
    return 2.0 / (4 * np.pi * sigma / S_two_electrode + 2.0 / length_m)


def _entries(S):
    iu = np.triu_indices(3)
    return S[iu]


def fit_angels4(x0=(0.010, 0.010, 0.010, 0.035), max_evaluations=6, verbose=True):
    """Least-squares fit of (radius, cap extent, ring width, ring centre) to the paper's S_BEM.

    Every evaluation is a mesh-converged free-space S from ring elements on the
    meridian (:func:`meridian_S_sigma_cm`, half a second), which is what the
    surface BEM with its edge correction returns in unbounded water.

    The table does not pin the four dimensions down: a valley runs from the
    preset's radius (1.15 cm, rms error 0.15 %) to 1.3 cm (0.04 %), the caps and
    rings shrinking as the radius grows. ``max_evaluations = 6`` is one
    Gauss-Newton step from ``x0`` (the earlier preset): the nearest dimensions
    that restore the fit, not a drift along the valley.
    """
    from scipy.optimize import least_squares

    target = _entries(PAPER_S_BEM_SIGMA_CM)
    history = []

    def residual(p):
        R, cap, w, xc = p
        try:
            S = meridian_S_sigma_cm(angels(4, R, cap, w, xc))
        except ValueError:
            return np.full(6, 1.0)
        r = _entries(S) / target - 1
        history.append((p.copy(), float(np.sqrt(np.mean(r**2)))))
        if verbose:
            print(f"  R={R*100:.4f} cap={cap*100:.4f} w={w*100:.4f} xc={xc*100:.4f} cm: "
                  f"rms rel error {history[-1][1]*100:.3f} %", flush=True)
        return r

    lo = [0.004, 0.004, 0.002, 0.015]
    hi = [0.016, 0.030, 0.030, 0.060]
    result = least_squares(residual, np.array(x0), bounds=(lo, hi), x_scale=[0.001] * 4, diff_step=1e-3,
                           max_nfev=max_evaluations)
    return result.x, history


def fit_angels2_cap(radius_m, ring_width_m, ring_centre_m, target_radius_m=PAPER_A2_RADIUS_M) -> float:
    """Cap extent (m) of angels-2 (the fitted body) whose free-space conductance gives the PSM radius
    ``target_radius_m`` (paper: 0.71 cm), by root finding on the ring-element model."""
    from scipy.optimize import brentq

    def gap(cap):
        S = meridian_S_sigma_cm(angels(2, radius_m, cap, ring_width_m, ring_centre_m))[0, 0] / 100.0
        return equivalent_radius_m(S) - target_radius_m

    return float(brentq(gap, 0.3 * radius_m, 1.5 * radius_m, xtol=1e-7))


def report_fit(p, cap_2_m=None, edge_length_m=None):
    """Entry-by-entry comparison with the paper; angels-2 with cap extent ``cap_2_m`` (default: angels-4's)."""
    R, cap, w, xc = p
    S = free_space_S_sigma_cm(angels(4, R, cap, w, xc), edge_length_m)
    print("angels-4 free-space S (sigma x cm): ours | paper | relative error")
    for i in range(3):
        for j in range(i, 3):
            ours, ref = S[i, j], PAPER_S_BEM_SIGMA_CM[i, j]
            print(f"  S[{i + 1},{j + 1}] {ours:9.4f} | {ref:9.4f} | {100 * (ours / ref - 1):+7.3f} %")
    errors = S / PAPER_S_BEM_SIGMA_CM - 1
    print(f"  mean |relative error| {100 * np.mean(np.abs(errors)):.3f} %, max {100 * np.max(np.abs(errors)):.3f} %")
    S2 = free_space_S_sigma_cm(angels(2, R, cap if cap_2_m is None else cap_2_m, w, xc), edge_length_m)[0, 0]
    a = equivalent_radius_m(S2 / 100.0)
    print(f"angels-2 free-space S = {S2:.4f} sigma cm -> PSM equivalent radius a = {a * 100:.4f} cm (paper: 0.71 cm)")
    return S, a


def tank_sweep(sensor, n_poses=17, sigma=SIGMA_PAPER, edge_length_m=None):
    """Resistance U/I wall to wall at y = 0 in the paper's 1 m tank."""
    from electrosense.bem.sweep import PoseSweep
    from electrosense.meshes.tank import Tank

    tank = Tank((1.0, 1.0, 1.0))
    half = tank.size_m[0] / 2 - sensor.length_m / 2 - 0.02
    x = np.linspace(-half, half, n_poses)
    poses = np.column_stack([x, np.zeros_like(x), np.zeros_like(x), np.zeros_like(x)])
    t0 = time.perf_counter()
    sweep = PoseSweep(sensor, tank, sigma_S_per_m=sigma, edge_length_m=edge_length_m)
    g = sweep.conductance(poses, progress=False)
    seconds = time.perf_counter() - t0
    print(f"{sensor.name} in the 1 m tank, sigma {sigma} S/m, y = 0 (tip 2 cm from the walls at the ends):")
    R = np.atleast_2d(g.resistance_ohm)
    for xi, r, it in zip(x, R, g.info["coupling_rank"]):
        print(f"  x = {xi:+.3f} m: " + "  ".join(f"R{k} = {v:7.2f} ohm" for k, v in zip(g.receivers, r))
              + f"   (coupling rank {it})")
    print(f"  {len(x)} poses in {seconds:.1f} s (sensor block {sweep.timings['sensor_block_s']:.1f} s, "
          f"tank block {sweep.timings.get('tank_block_s', 0):.1f} s); paper: ~600 ohm mid-tank, rising to the walls")
    return x, R


def richardson(values, ratio):
    """Extrapolated limit and observed order from three values at h, h/ratio, h/ratio^2."""
    v0, v1, v2 = values
    d1, d2 = v1 - v0, v2 - v1
    if d1 == 0 or d2 == 0 or np.sign(d1) != np.sign(d2):
        return v2, np.nan
    p = np.log(abs(d1 / d2)) / np.log(ratio)
    limit = v2 + d2 / (ratio**p - 1)
    return limit, p


def _max_relative(S, reference):
    return float(np.max(np.abs(np.asarray(S) / np.asarray(reference) - 1)))


def convergence(sensor, sigma=SIGMA_PAPER, tank_order=2.0):
    """Default-mesh conductance matrix against mesh-converged references, in free space, mid-tank and
    with the tip 1 cm from a wall. Errors are the largest relative error over the entries of S.

    * Free space: the converged S from ring elements on the meridian (:func:`electrosense.bem.meridian.converged_conductance`,
      Richardson over three meridians, observed order 2) against the surface BEM at the default mesh,
      without and with the edge correction.
    * In the tank (sensor mesh at its default, with the edge correction): the tank mesh refined by 2
      (edge length at the sensor and its growth both halved) and extrapolated with order ``tank_order``
      (flat P0 panels on the flat walls; observed 1.9 for angels-2 near a wall over refinements 1, 2, 4);
      and the sensor mesh refined by sqrt 2 (grading too) at the default tank, whose change bounds what
      the edge correction leaves of the sensor's own error.
    """
    from electrosense.bem.conductance import S_from_K
    from electrosense.bem.meridian import converged_conductance
    from electrosense.bem.solve import conductance_matrix, solve_scene
    from electrosense.meshes.pose import Pose
    from electrosense.meshes.scene import Scene
    from electrosense.meshes.scene_mesh import DEFAULT_TANK_GRADING, default_tank_edge_length_m
    from electrosense.meshes.sensor_mesh import default_edge_length_m
    from electrosense.meshes.tank import Tank

    def default_and_raw_S(scene):
        """S at the default meshes, with and without the edge correction (one solve)."""
        solution = solve_scene(scene, sigma)
        return (solution, S_from_K(solution.K_S, sensor.emitter),
                S_from_K(solution.K_surface_S, sensor.emitter))

    reference = converged_conductance(sensor, sigma)
    free, corrected, raw = default_and_raw_S(Scene(sensor))
    print(f"{sensor.name} free space: converged S by ring elements ({reference.info['elements']} elements, "
          f"observed order {np.nanmean(reference.info['observed_order']):.2f}, finest within "
          f"{100 * reference.info['finest_departure']:.4f} %); default surface mesh "
          f"({free.boundary.n_triangles} triangles) off by {100 * _max_relative(raw, reference.S_S):.3f} % "
          f"without the edge correction, {100 * _max_relative(corrected, reference.S_S):.4f} % with it "
          f"(target 0.3 %)", flush=True)
    tank = Tank((1.0, 1.0, 1.0))
    h0, ht = default_edge_length_m(sensor), default_tank_edge_length_m(sensor)
    near_x = tank.size_m[0] / 2 - sensor.length_m / 2 - 0.01
    for label, pose in (("mid-tank", Pose(0, 0, 0, 0)), ("tip 1 cm from a wall", Pose(near_x, 0, 0, 0))):
        scene = Scene(sensor, pose, tank)
        t0 = time.perf_counter()
        solution, default, raw = default_and_raw_S(scene)
        finer_tank = conductance_matrix(scene, sigma, tank_edge_length_m=ht / 2, tank_grading=DEFAULT_TANK_GRADING / 2)
        limit = finer_tank.S_S + (finer_tank.S_S - default) / (2**tank_order - 1)
        finer_sensor = conductance_matrix(scene, sigma, edge_length_m=h0 / np.sqrt(2), grading=1 + 0.15 / np.sqrt(2))
        tank_part = _max_relative(default, limit)
        sensor_part = _max_relative(default, finer_sensor.S_S)
        print(f"{sensor.name} {label}: default meshes ({solution.boundary.n_triangles} triangles) off the tank-converged S "
              f"by {100 * tank_part:.3f} % (tank mesh halved: {finer_tank.info['triangles']} triangles); the sensor "
              f"mesh refined by sqrt 2 moves S by {100 * sensor_part:.3f} %; together within "
              f"{100 * (tank_part + sensor_part):.3f} % (target 0.3 %); without the edge correction "
              f"{100 * _max_relative(raw, limit):.3f} %; {time.perf_counter() - t0:.0f} s", flush=True)


def wall_convergence(sensor, gaps_m=(0.005, 0.02, 0.1), reference_ratio: float = 0.125):
    """The tank mesh near a wall: K with the sensor heading at the end wall of the 1 m tank, tip ``gaps_m`` from
    it, on the default tank mesh, on it without the bound of its edge by the distance from the sensor's surface
    (:data:`~electrosense.meshes.scene_mesh.DEFAULT_TANK_NEAR_RATIO`), and with a bound of 0.25, against a tank
    mesh with that bound at ``reference_ratio`` (the default grading and floor otherwise). Largest relative error
    over the receivers' currents; triangles and CPU seconds of each solve."""
    from electrosense.bem import PoseSweep
    from electrosense.meshes.pose import Pose
    from electrosense.meshes.scene import Scene
    from electrosense.meshes.scene_mesh import DEFAULT_TANK_NEAR_RATIO, sensor_axis_points_m
    from electrosense.meshes.tank import Tank

    tank = Tank((1.0, 1.0, 1.0))
    e = sensor.emitter - 1
    r = [k for k in range(sensor.n_electrodes) if k != e]
    cases = {"default": DEFAULT_TANK_NEAR_RATIO, "no bound": None, "bound 0.25": 0.25,
             f"reference {reference_ratio:g}": reference_ratio}
    print(f"{sensor.name} heading at the end wall of the 1 m tank: receiver currents against a tank mesh whose edge "
          f"is at most {reference_ratio:g}x its distance from the sensor's surface (CPU: the tank's set-up and "
          "the pose, the sensor's block factorised once)")
    sweep = PoseSweep(sensor, tank)
    for gap in gaps_m:
        pose = Pose(tank.size_m[0] / 2 - sensor.length_m / 2 - gap, 0.0, 0.0, 0.0)
        focus = sensor_axis_points_m(Scene(sensor, pose, tank), 9)
        out = {}
        for label, ratio in cases.items():
            c0 = time.process_time()
            at = sweep.with_focus(focus, tank_near_ratio=ratio)
            K = at.conductance(pose.as_array()[None]).K_S[0]
            out[label] = (K[r, e], at.tank_mesh.n_triangles, time.process_time() - c0)
        reference = out.pop(f"reference {reference_ratio:g}")
        row = "; ".join(f"{label} {100 * np.abs(I / reference[0] - 1).max():.3f} % ({n} triangles, {cpu:.1f} s CPU)"
                        for label, (I, n, cpu) in out.items())
        print(f"  tip {1e3 * gap:g} mm from the wall: {row}; reference {reference[1]} triangles", flush=True)


def fine_reference(sensor, sigma=SIGMA_PAPER, divisions=(1, 2, 4, 8), targets_per_class=8):
    """Free-space I1/U on meshes refined far past the default (h0 / d), by the axisymmetric reduction.

    Refining only the edge length keeps the grading ratio ``g`` towards the electrode edges: the graded zone keeps its element size relative to the distance from the edge,
    ``g - 1``, and its error does not shrink (observed order 0.3 or less, no asymptotic range). Here
    the mesh family refines that zone too, ``g = 1 + (g0 - 1) / d`` at ``h0 / d``: the observed order
    comes out between 1 and 1.5 and the Richardson limit is a reference worth the name. Up to h0/8
    (some 210 000 triangles for angels-2) in seconds to a minute with the reduction.
    """
    import inspect

    from electrosense.bem.axisymmetric import solve_axisymmetric
    from electrosense.bem.boundary_conditions import WaterBoundary
    from electrosense.meshes.sensor_mesh import default_edge_length_m, mesh_sensor

    h0 = default_edge_length_m(sensor)
    g0 = inspect.signature(mesh_sensor).parameters["grading"].default
    values = []
    for d in divisions:
        mesh = mesh_sensor(sensor, edge_length_m=h0 / d, grading=1 + (g0 - 1) / d)
        solution = solve_axisymmetric(WaterBoundary.from_meshes(mesh, emitter=sensor.emitter), sigma, None,
                                      sensor.emitter, targets_per_class=None if d == 1 else targets_per_class)
        values.append(solution.conductance.receiver_currents_A(1.0)[0])
        print(f"{sensor.name} free space, h0/{d}, grading {1 + (g0 - 1) / d:.4f}: {mesh.n_triangles} triangles, I1/U = {values[-1]:.7e} S", flush=True)
    print(f"  default mesh {100 * (values[0] / values[-1] - 1):+.3f} % from the finest (h0/{divisions[-1]})")
    if len(values) >= 3:
        limit, p = richardson(values[-3:], 2.0)
        if not p > 0:
            print("  no asymptotic range yet (the differences do not shrink): Richardson does not apply")
            return values
        print(f"  Richardson over the three finest (ratio 2): limit {limit:.7e} S, observed order {p:.2f}; "
              f"default mesh off by {100 * (values[0] / limit - 1):+.3f} %, finest by "
              f"{100 * (values[-1] / limit - 1):+.3f} %")
        from electrosense.bem.meridian import converged_conductance

        ring = converged_conductance(sensor, sigma).receiver_currents_A(1.0)[0]
        print(f"  ring elements on the meridian (an independent discretisation), converged: {ring:.7e} S, "
              f"{100 * (ring / limit - 1):+.4f} % from the surface meshes' limit")
    return values


def main(argv=None):
    parser = argparse.ArgumentParser(prog="bem_paper", description=__doc__.splitlines()[0])
    parser.add_argument("--fit", action="store_true", help="fit the angels-4 dimensions (minutes)")
    parser.add_argument("--sweep", action="store_true", help="angels-2 wall-to-wall sweep in the 1 m tank")
    parser.add_argument("--convergence", action="store_true", help="Richardson mesh convergence")
    parser.add_argument("--fine-reference", action="store_true",
                        help="free-space convergence far past the default mesh (h0/8, axisymmetric)")
    parser.add_argument("--wall", action="store_true",
                        help="the tank mesh near a wall: default against a mesh refined by the distance from the sensor")
    parser.add_argument("--poses", type=int, default=17, help="poses of the sweep")
    args = parser.parse_args(argv)
    everything = not (args.fit or args.sweep or args.convergence or args.fine_reference or args.wall)
    from electrosense.meshes.sensor import _ANGELS_DIMENSIONS, preset

    if args.fit or everything:
        d = _ANGELS_DIMENSIONS
        x0 = (d["radius_m"], d["cap_extent_m"], d["ring_width_m"], d["ring_centre_m"])
        p, history = fit_angels4(x0)
        print("fitted: radius %.4f cm, cap extent %.4f cm, ring width %.4f cm, ring centre +-%.4f cm"
              % tuple(100 * np.asarray(p)))
        cap_2 = fit_angels2_cap(p[0], p[2], p[3])
        print(f"angels-2 cap extent for a = {PAPER_A2_RADIUS_M * 100} cm: {cap_2 * 100:.4f} cm")
        report_fit(p, cap_2)
    else:
        d = _ANGELS_DIMENSIONS
        report_fit((d["radius_m"], d["cap_extent_m"], d["ring_width_m"], d["ring_centre_m"]), d.get("cap_extent_2_m"))
    if args.sweep or everything:
        tank_sweep(preset("angels-2"), args.poses)
    if args.convergence or everything:
        for name in ("angels-2", "angels-4"):
            convergence(preset(name))
    if args.fine_reference or everything:
        for name in ("angels-2", "angels-4"):
            fine_reference(preset(name))
    if args.wall or everything:
        wall_convergence(preset("angels-4"))


if __name__ == "__main__":
    main()
