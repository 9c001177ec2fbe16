"""The electrode-edge correction in a scene, against an exact reference: a sensor's tip facing a wall square on.

The surface BEM's error is almost all at the electrode edges, measured once in unbounded water
(:mod:`electrosense.bem.edge_correction`) and carried into every scene. How it is carried matters where the scene
changes K most, a few millimetres from a wall: added as a constant it keeps its free-space size; scaled
(:func:`~electrosense.bem.edge_correction.scaled_to_scene`, the BEM's) it follows each pair's conductance.

A sensor of revolution whose axis meets a plane insulating wall square on is still a problem of revolution:
ring elements with the wall's image (:func:`electrosense.bem.meridian.converged_conductance` with ``wall_x_m``;
Richardson over three meridians, 1e-5) give its K converged, by other code than the surface BEM. The surface BEM
solves the same scene as the sensor and its mirror image in unbounded water, each electrode and its image one
electrode (by symmetry the mid-plane carries no current: the wall exactly, with no wall mesh), half of whose K
is the sensor's. Printed for each sensor mesh (its edge length times the default) and gap between the tip and
the wall: the wall's change of K, and the error of the surface K uncorrected, with the correction constant and
scaled, as the largest entry's error over max|K| and as the largest relative error of a mutual conductance.
Free space (no wall) is the first row: both forms agree there, and what is left is the correction's own
reference (its meridian, within about 1e-4 of converged).

Run: ``esense study edge_correction_wall [--sensor angels-4|random] [--seed S] [--scales 1.3,1.0]
[--gaps 0.005,0.01,0.02,0.05]``. ``random`` draws a sensor as the diagnosis's unseen set-ups do. 6 minutes
wall / 470 s CPU on two cores for angels-4 with the defaults; 9 minutes / 710 s for the random sensor of seed 3
at ``--scales 1 --gaps 0.005,0.02`` (each surface solve holds twice the sensor's triangles).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from electrosense.validation.studies import positive_numbers

DEFAULT_GAPS_M = (0.005, 0.01, 0.02, 0.05)
DEFAULT_SCALES = (1.3, 1.0)


def mirrored(mesh, wall_x_m: float):
    """The sensor mesh reflected in the plane ``x = wall_x_m`` (faces rewound: normals still into the water)."""
    from electrosense.meshes.labelled_mesh import LabelledMesh

    v = mesh.vertices_m.copy()
    v[:, 0] = 2.0 * wall_x_m - v[:, 0]
    return LabelledMesh(v, mesh.faces[:, ::-1], mesh.electrode, mesh.region, mesh.region_names)


def surface_K_facing_wall(mesh, sigma_S_per_m: float, wall_x_m: float) -> np.ndarray:
    """The surface BEM's K (no correction) of the sensor mesh (own frame) with an insulating wall at
    ``x = wall_x_m``: the sensor and its mirror image, each electrode and its image one electrode, in unbounded
    water; half the currents are the sensor's."""
    from electrosense.bem.boundary_conditions import WaterBoundary
    from electrosense.bem.solution import solve
    from electrosense.meshes.labelled_mesh import concatenate

    pair = concatenate([mesh, mirrored(mesh, wall_x_m)])
    return 0.5 * solve(WaterBoundary.from_meshes(pair, check=False), sigma_S_per_m).K_S


def errors(K, reference, emitter: int) -> tuple[float, float]:
    """(largest error over max|reference| (%), largest relative error of the emitter's mutual conductances (%))."""
    e = emitter - 1
    others = [k for k in range(len(K)) if k != e]
    scale = np.abs(reference).max()
    mutual = np.abs((K - reference)[others, e] / reference[others, e]).max()
    return 100 * np.abs(K - reference).max() / scale, 100 * mutual


def compare(sensor, scales=DEFAULT_SCALES, gaps_m=DEFAULT_GAPS_M, sigma_S_per_m: float = 1.0) -> list[dict]:
    """One row per sensor mesh and gap (``gap_m`` None: free space) with the errors of the three forms (%)."""
    from electrosense.bem.edge_correction import free_space_correction_with_K, scaled_to_scene
    from electrosense.bem.meridian import converged_conductance
    from electrosense.meshes.sensor_mesh import default_edge_length_m, mesh_sensor

    tip_x_m = 0.5 * sensor.length_m
    references = {None: converged_conductance(sensor, sigma_S_per_m).K_S}
    for gap in gaps_m:
        references[gap] = converged_conductance(sensor, sigma_S_per_m, wall_x_m=tip_x_m + gap).K_S
    rows = []
    for scale in scales:
        mesh = mesh_sensor(sensor, scale * default_edge_length_m(sensor))
        dK, free_K = free_space_correction_with_K(sensor, sigma_S_per_m, None, mesh, disk_cache=False)
        for gap, reference in references.items():
            c0 = time.process_time()
            K = free_K if gap is None else surface_K_facing_wall(mesh, sigma_S_per_m, tip_x_m + gap)
            forms = {"none": K, "constant": K + dK, "scaled": K + scaled_to_scene(dK, free_K, K)}
            row = dict(scale=scale, triangles=mesh.n_triangles, gap_m=gap,
                       wall_change=100 * np.abs(reference - references[None]).max() / np.abs(reference).max(),
                       cpu_s=time.process_time() - c0)
            for name, K_form in forms.items():
                row[name] = errors(K_form, reference, sensor.emitter)
            rows.append(row)
    return rows


def print_rows(rows) -> None:
    print("error of the surface K against the converged one: of max|K| (%), and the largest relative error of the "
          "emitter's mutual conductances (%), uncorrected / correction constant / scaled (the BEM's)")
    print(f"{'mesh':>5} {'sensor tris':>11} {'gap':>7} {'wall: dK/K':>10} | {'max|K|: none':>12} {'constant':>8} "
          f"{'scaled':>7} | {'mutual: none':>12} {'constant':>8} {'scaled':>7} | {'CPU s':>5}")
    for r in rows:
        gap = "free" if r["gap_m"] is None else f"{1e3 * r['gap_m']:.0f} mm"
        print(f"{r['scale']:>4.2f}x {r['triangles']:>11d} {gap:>7} {r['wall_change']:>8.2f} % | "
              f"{r['none'][0]:>12.4f} {r['constant'][0]:>8.4f} {r['scaled'][0]:>7.4f} | "
              f"{r['none'][1]:>12.4f} {r['constant'][1]:>8.4f} {r['scaled'][1]:>7.4f} | {r['cpu_s']:>5.0f}")


def main(argv=None):
    parser = argparse.ArgumentParser(prog="edge_correction_wall", description=__doc__.splitlines()[0])
    parser.add_argument("--sensor", default="angels-4", help="a preset's name (default angels-4), or random")
    parser.add_argument("--seed", type=int, default=3, help="the random sensor's seed")
    parser.add_argument("--scales", default=",".join(f"{s:g}" for s in DEFAULT_SCALES),
                        help="sensor meshes: edge length over the default, comma separated")
    parser.add_argument("--gaps", default=",".join(f"{g:g}" for g in DEFAULT_GAPS_M),
                        help="gaps (m) between the head tip and the wall, comma separated")
    args = parser.parse_args(argv)
    from electrosense.meshes import preset

    scales, gaps = positive_numbers(parser, "--scales", args.scales), positive_numbers(parser, "--gaps", args.gaps)
    if args.sensor == "random":
        from electrosense.validation.diagnosis.unseen import random_sensor

        sensor = random_sensor(np.random.default_rng(args.seed))
    else:
        sensor = preset(args.sensor)
    print(f"{sensor.name}: {sensor.n_electrodes} electrodes, length {sensor.length_m:.3f} m, its head tip facing "
          f"an insulating wall square on; reference: ring elements with the wall's image, converged")
    t0, c0 = time.perf_counter(), time.process_time()
    print_rows(compare(sensor, scales, gaps))
    print(f"{time.perf_counter() - t0:.0f} s wall, {time.process_time() - c0:.0f} s CPU")


if __name__ == "__main__":
    main()
