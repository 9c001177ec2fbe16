"""Blind diagnosis of set-ups it has never seen: random sensors and tanks, data by the BEM, the default command.

Each case draws a sensor (3-6 electrodes), a partly filled box tank, a
conductivity and passes (:mod:`electrosense.validation.diagnosis.unseen`), makes the
bench data with the BEM (a finer tank mesh than the diagnosis uses, and the
*true* scene: the effect in the BEM's physics), writes a bench log and runs
``esense diagnose LOG -o DIR`` with its defaults. Printed: per case, the
injected effect, what was chosen, the verdict, the held-out gap before and
after, the noise and the baseline's own error budget, whether the BEM
confirms the chosen effect's fitted scene, the wall and CPU time;
then the rates of the done-when criteria. A second log of the same set-up
(new noise) is diagnosed again, to time the cached path.

Run: ``python -m electrosense.validation.studies.diagnosis_blind_unseen [--cases 6] [--seed 0] [--per-pass 41]``
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

#: (effect, world arguments, output-side arguments of assemble, acceptable first names)
CASES = {
    "none": (None, {}, {}, ("none",)),
    "conductivity": (None, {}, {"conductivity": -0.025}, ("conductivity",)),
    "channel_gain": (None, {}, {"gains": "random"}, ("channel_gain",)),
    "contact_impedance": ("contact_impedance", {"z_c_ohm_m2": 0.002}, {}, ("contact_impedance",)),
    "tank_size": ("tank_size", {"dLx_m": -0.03}, {}, ("tank_size",)),
    "water_depth": ("water_depth", {"d_m": -0.04}, {}, ("water_depth",)),
    "unmodelled_object": ("object", {"radius_m": 0.025}, {}, ("unmodelled_object",)),
    "insulating_object": ("object", {"radius_m": 0.025, "insulating": True}, {}, ("unmodelled_object",)),
    "pose_offset": ("pose_offset", {"dx_m": 0.003, "dy_m": -0.002, "dyaw_rad": 0.0}, {}, ("pose_offset",)),
    "heading_offset": ("pose_offset", {"dx_m": 0.0, "dy_m": 0.0, "dyaw_rad": 0.035}, {}, ("pose_offset",)),
    "object_and_drift": ("object", {"radius_m": 0.025}, {"drift_per_hour": 0.02},
                         ("unmodelled_object", "temperature_drift")),
    # out of the library: the right answer is the nearest physical name or `unexplained`
    "elongated_object": ("elongated", {}, {}, ("unmodelled_object", "unexplained")),
    "two_objects": ("two_objects", {}, {}, ("unmodelled_object", "unexplained")),
}

#: the world's sensor mesh edge, in units of the mesher's default: finer than the diagnosis's anchors
#: (:data:`electrosense.validation.diagnosis.anchored.SENSOR_EDGE_FACTOR`), so that data and baseline never share a mesh
WORLD_SENSOR_EDGE_FACTOR = 2.0


def world_scene(setup, poses, effect, args, rng):
    """(tank, objects, contact impedance) of the true scene."""
    from electrosense.meshes.objects import Box, Sphere
    from electrosense.meshes.tank import Tank

    tank, objects, z = setup.tank, (), None
    lx, ly, lz = tank.size_m
    if effect == "contact_impedance":
        z = args["z_c_ohm_m2"]
    elif effect == "tank_size":
        tank = Tank((lx + args["dLx_m"], ly, lz), tank.water_depth_m)
        if not _scene_ok(setup.sensor, poses, tank):  # the walls came in onto the path's ends: move them out
            tank = Tank((lx - args["dLx_m"], ly, lz), setup.tank.water_depth_m)
    elif effect == "water_depth":
        tank = Tank((lx, ly, lz), tank.water_depth_m + args["d_m"])
    elif effect in ("object", "elongated", "two_objects"):
        # beside pass 0 (y = 0, mid-depth), a little off the line
        x = float(rng.uniform(-0.25, 0.25) * lx)
        zc = float(poses[0, 2])
        side = float(rng.choice([-1.0, 1.0]))
        r = setup.sensor.radius_m
        if effect == "object":
            b = args["radius_m"]
            material = 0.0 if args.get("insulating") else np.inf
            objects = (Sphere((x, side * (r + b + 0.03), zc), conductivity_S_per_m=material, radius_m=b),)
        elif effect == "elongated":
            objects = (Box((x, side * (r + 0.045), zc), conductivity_S_per_m=0.0, size_m=(0.12, 0.02, 0.03), yaw_rad=0.3),)
        else:
            objects = (Sphere((x, side * (r + 0.05), zc), conductivity_S_per_m=np.inf, radius_m=0.02),
                       Sphere((-x, -side * (r + 0.05), zc), conductivity_S_per_m=0.0, radius_m=0.025))
        # an object on another pass's path (the robot would have hit it) is moved up, above every pass
        objects = tuple(o if _scene_ok(setup.sensor, poses, None, (o,)) else
                        _replace_centre(o, (o.centre_m[0], o.centre_m[1], float(np.max(poses[:, 2])) + r + 0.045))
                        for o in objects)
    return tank, objects, z


def _replace_centre(obj, centre_m):
    from dataclasses import replace

    return replace(obj, centre_m=tuple(centre_m))


def _scene_ok(sensor, poses, tank=None, objects=()) -> bool:
    """Whether the scene checker accepts the sensor at every pose in ``tank`` beside ``objects``."""
    from electrosense.meshes.pose import Pose
    from electrosense.meshes.scene import Scene
    from electrosense.meshes.scene_mesh import SceneError, check_scene

    try:
        for p in np.asarray(poses, float):
            check_scene(Scene(sensor, Pose.from_array(p), tank, tuple(objects)))
    except SceneError:
        return False
    return True


def true_poses(poses, effect, args):
    """The poses the sensor really took: the logged ones, moved by a robot-frame offset for ``pose_offset``
    (true position = rotation(dyaw) logged position + (dx, dy), true yaw = logged yaw + dyaw)."""
    poses = np.array(poses, float)
    if effect != "pose_offset":
        return poses
    c, s = np.cos(args["dyaw_rad"]), np.sin(args["dyaw_rad"])
    x, y = poses[:, 0].copy(), poses[:, 1].copy()
    poses[:, 0] = c * x - s * y + args["dx_m"]
    poses[:, 1] = s * x + c * y + args["dy_m"]
    poses[:, 3] += args["dyaw_rad"]
    return poses


def world_K(setup, poses, effect, args, rng, cache: Path):
    """The BEM's K (P, n, n) of the true scene, cached in ``cache`` by a hash of everything it depends on."""
    import hashlib

    from electrosense.bem import PoseSweep
    from electrosense.meshes.scene_mesh import trajectory_focus_m
    from electrosense.meshes.sensor_mesh import default_edge_length_m

    tank, objects, z = world_scene(setup, poses, effect, args, rng)
    poses = true_poses(poses, effect, args)
    key = hashlib.sha256(repr((setup.sensor.to_dict(), tank, objects, z, np.round(poses, 9).tolist(),
                               setup.sigma_S_per_m)).encode()).hexdigest()[:20]
    path = cache / f"world-{key}.npy"
    if path.exists():
        return np.load(path)
    sweep = PoseSweep(setup.sensor, tank, objects, sigma_S_per_m=setup.sigma_S_per_m, contact_impedance_ohm_m2=z,
                      edge_length_m=WORLD_SENSOR_EDGE_FACTOR * default_edge_length_m(setup.sensor),
                      focus_m=trajectory_focus_m(setup.sensor, poses))
    K = sweep.conductance(poses, progress=True).K_S
    cache.mkdir(parents=True, exist_ok=True)
    np.save(path, K)
    return K


def make_log(case: str, seed: int, folder: Path, per_pass: int = 41, n_electrodes: int | None = None,
             noise_seed: int = 0, cache: Path | None = None):
    """Write the bench log of one blind case; returns (path, setup, truth)."""
    from electrosense.validation.diagnosis.blind import assemble, write_log
    from electrosense.validation.diagnosis.forward import receiver_currents
    from electrosense.validation.diagnosis.unseen import random_passes, random_setup

    rng = np.random.default_rng(seed)
    setup = random_setup(rng, n_electrodes)
    poses, t, passes = random_passes(setup, rng, 3, per_pass)
    effect, wargs, output, ok = CASES[case]
    output = dict(output)
    if output.get("gains") == "random":
        g = rng.uniform(-1, 1, setup.sensor.n_electrodes - 1)
        output["gains"] = 0.01 * g / np.max(np.abs(g))
    cache = cache or Path(os.environ.get("ESENSE_CACHE_DIR", tempfile.gettempdir())) / "blind-worlds"
    K = world_K(setup, poses, effect, wargs, np.random.default_rng(seed + 1), cache)
    I = receiver_currents(K, setup.sensor.emitter)
    obs = assemble(setup, poses, t, passes, I, np.random.default_rng(1000 + noise_seed), **output)
    folder.mkdir(parents=True, exist_ok=True)
    from electrosense.meshes.sensor import save_sensor

    save_sensor(setup.sensor, folder / f"sensor-{seed}.json")  # a sensor file, not a preset
    obs.meta["sensor"] = f"sensor-{seed}.json"
    path = write_log(obs, folder / f"{case}-{seed}-{noise_seed}.csv")
    return path, setup, {"case": case, "acceptable": list(ok)}


def run_cli(log: Path, out: Path) -> tuple[dict, float, float]:
    """``esense diagnose LOG -o OUT`` (defaults) in this process; (diagnosis.json, wall s, CPU s)."""
    from click.testing import CliRunner

    from electrosense.validation.cli import main

    w0, c0 = time.perf_counter(), time.process_time()
    res = CliRunner().invoke(main, ["diagnose", str(log), "-o", str(out), "--no-figures"])
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    if res.exit_code != 0:
        raise RuntimeError(f"diagnose failed on {log}: {res.output}\n{res.exception!r}")
    return json.loads((out / "diagnosis.json").read_text()), wall, cpu


def judge(d: dict, acceptable) -> dict:
    first = d["chosen"][0] if d["chosen"] else d["verdict"]
    named = bool(d["chosen"]) and d["chosen"] != ["none"]
    floor = d.get("model_error", {}).get("noise_floor", d["noise"])
    shrink_ok = (not named) or d["gap_after"] <= max(0.2 * d["gap_before"], 1.2 * floor)
    return {"first": first, "right": first in acceptable, "shrink_ok": shrink_ok}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=",".join(CASES), help="comma list of cases")
    ap.add_argument("--seeds", default="0", help="comma list of set-up seeds")
    ap.add_argument("--per-pass", type=int, default=41)
    ap.add_argument("--electrodes", type=int, default=None, help="electrodes of every sensor (default: 3-6)")
    ap.add_argument("--second", action="store_true", help="diagnose a second log of each set-up (timing)")
    args = ap.parse_args(argv)
    folder = Path(tempfile.mkdtemp(prefix="blind-unseen-"))
    rows = []
    for seed in [int(s) for s in args.seeds.split(",")]:
        for case in args.cases.split(","):
            t0 = time.perf_counter()
            log, setup, truth = make_log(case, seed, folder, args.per_pass, args.electrodes)
            t_data = time.perf_counter() - t0
            d, wall, cpu = run_cli(log, folder / f"diag-{case}-{seed}")
            j = judge(d, truth["acceptable"])
            budget = d.get("model_error", {})
            row = {"seed": seed, "case": case, "n_el": setup.sensor.n_electrodes, "chosen": d["chosen"],
                   "verdict": d["verdict"], "gap_before": d["gap_before"], "gap_after": d["gap_after"],
                   "noise": d["noise"], "baseline_error": budget.get("baseline_rms"),
                   "bem_confirms": (d.get("bem_check") or {}).get("confirmed"), "wall_s": wall, "cpu_s": cpu,
                   "data_s": t_data, **j}
            if args.second:
                log2, _, _ = make_log(case, seed, folder, args.per_pass, args.electrodes, noise_seed=1)
                d2, wall2, cpu2 = run_cli(log2, folder / f"diag2-{case}-{seed}")
                row.update(second_wall_s=wall2, second_cpu_s=cpu2, second_chosen=d2["chosen"])
            rows.append(row)
            print(json.dumps({k: (round(v, 6) if isinstance(v, float) else v) for k, v in row.items()}), flush=True)
    n = len(rows)
    print(f"\n{n} cases: right first name {sum(r['right'] for r in rows)}/{n}, "
          f"shrink criterion {sum(r['shrink_ok'] for r in rows)}/{n}")
    print(f"diagnosis wall time: median {np.median([r['wall_s'] for r in rows]):.1f} s, "
          f"max {max(r['wall_s'] for r in rows):.1f} s; CPU median {np.median([r['cpu_s'] for r in rows]):.1f} s")
    if args.second:
        print(f"second log: wall median {np.median([r['second_wall_s'] for r in rows]):.1f} s, "
              f"max {max(r['second_wall_s'] for r in rows):.1f} s")


if __name__ == "__main__":
    main()
