"""A flat face as an image plane against the same face meshed: K, triangles and CPU seconds by the gap.

For a sensor lying along a wall (heading along it, a few degrees off), at several gaps between its surface and
the wall, K of the receivers (the emitter's column) from :class:`~electrosense.bem.PoseSweep`

* with the BEM's default tank mesh (its edge near the sensor at most 0.35x the distance from it),
* with the wall an image plane (:mod:`electrosense.bem.image_plane`), the rest of the tank meshed alike,
* at the smallest gap, with the tank mesh's edge bounded at 0.2x the distance (the mesh refined where it errs),

on the reference sensor mesh and on one 3x coarser (a tank map's coarse poses). Printed: the largest relative
difference of each meshed K from the image's, and the triangles and CPU seconds (the tank's set-up and the pose;
the sensor block factorised once, before the clock). The meshed BEM converging towards the image as its wall
mesh is refined is the check that the image is the converged K.

Run: ``esense study image_plane [--sensor angels-4|random] [--seed S] [--gaps 0.005,0.01,0.02,0.04,0.08]
[--no-fine]``; ``random`` (the default) draws a 5-electrode sensor and a box as the tank map study does.
About 3 minutes on two cores for angels-4 in the 1 m tank (the fine mesh at 5 mm, 22 000 triangles, is 2 of
them; ``--no-fine`` leaves it out).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from electrosense.validation.studies import positive_numbers

DEFAULT_GAPS_M = (0.005, 0.01, 0.02, 0.04, 0.08)
#: the edge bound of the finer meshed reference at the smallest gap
FINE_NEAR_RATIO = 0.2


def lying_along_a_wall(sensor, tank, gap_m: float, yaw: float = 0.03):
    """(pose (4,), the wall's name): the sensor's centre on the tank's axis in x, heading ``yaw`` off the +y
    wall, its nearest point ``gap_m`` from it."""
    reach = sensor.radius_m + (0.5 * sensor.length_m - sensor.radius_m) * abs(np.sin(yaw))
    z = 0.5 * (tank.floor_z_m + tank.free_surface_z_m)
    return np.array([0.0, 0.5 * tank.size_m[1] - reach - gap_m, z, yaw]), "wall_y+"


def compare(sensor, tank, gaps_m=DEFAULT_GAPS_M, fine: bool = True, coarse_factor: float = 3.0) -> list[dict]:
    """One row per sensor mesh and gap: the meshed K's largest relative difference from the image's, and each
    solve's tank triangles and CPU seconds."""
    from electrosense.bem import PoseSweep
    from electrosense.meshes.sensor_mesh import default_edge_length_m

    e = sensor.emitter - 1
    r = [k for k in range(sensor.n_electrodes) if k != e]
    rows = []
    for mesh, edge in (("reference", None), ("coarse", coarse_factor * default_edge_length_m(sensor))):
        sweep = PoseSweep(sensor, tank, sigma_S_per_m=1.0, edge_length_m=edge, tol=1e-5)
        for gap in gaps_m:
            pose, wall = lying_along_a_wall(sensor, tank, gap)
            cases = {"image": {"image_face": wall}, "default": {}}
            if fine and mesh == "reference" and gap == min(gaps_m):
                cases[f"bound {FINE_NEAR_RATIO:g}"] = {"tank_near_ratio": FINE_NEAR_RATIO}
            out = {}
            for label, options in cases.items():
                c0 = time.process_time()
                at = sweep.with_focus(**{"tank_near_ratio": sweep.tank_near_ratio, **options})
                K = at.conductance(pose[None]).K_S[0]
                out[label] = (K[r, e], len(at.env_tris), time.process_time() - c0)
            I_image = out["image"][0]
            rows.append({"mesh": mesh, "sensor_triangles": sweep.sensor_mesh.n_triangles, "gap_m": gap,
                         **{label: {"triangles": n, "cpu_s": cpu,
                                    "against_image": float(np.abs(I / I_image - 1).max())}
                            for label, (I, n, cpu) in out.items()}})
    return rows


def print_rows(rows) -> None:
    for row in rows:
        cells = "; ".join(f"{label} {v['triangles']} triangles, {v['cpu_s']:.1f} s"
                          + ("" if label == "image" else f", {100 * v['against_image']:.3f} % from the image")
                          for label, v in row.items() if isinstance(v, dict))
        print(f"  {row['mesh']} sensor mesh ({row['sensor_triangles']} triangles), gap {1e3 * row['gap_m']:g} mm: "
              f"{cells}", flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser(prog="image_plane", description=__doc__.splitlines()[0])
    parser.add_argument("--sensor", default="random", help="a preset's name, or random (default)")
    parser.add_argument("--seed", type=int, default=4, help="the random sensor's and tank's seed")
    parser.add_argument("--gaps", default=",".join(f"{g:g}" for g in DEFAULT_GAPS_M),
                        help="gaps (m) between the sensor's surface and the wall, comma separated")
    parser.add_argument("--no-fine", action="store_true", help="leave out the finer meshed reference")
    args = parser.parse_args(argv)
    from electrosense.meshes import preset
    from electrosense.meshes.tank import Tank

    gaps = positive_numbers(parser, "--gaps", args.gaps)
    if args.sensor == "random":
        from electrosense.validation.studies.tank_map import random_scene

        sensor, tank, _ = random_scene(np.random.default_rng(args.seed), cylinder=False)
    else:
        sensor, tank = preset(args.sensor), Tank((1.0, 1.0, 1.0))
    print(f"{sensor.name}: {sensor.n_electrodes} electrodes, length {sensor.length_m:.3f} m, lying "
          f"along the +y wall of {tank} (3 degrees off); K of the receivers, meshed against the wall as an image")
    print_rows(compare(sensor, tank, gaps, fine=not args.no_fine))


if __name__ == "__main__":
    main()
