"""Generate the BEM blind-test data of the gap diagnosis (tests/data/diagnosis/bem_worlds.npz).

The BEM (:class:`electrosense.bem.PoseSweep`) is run at the two passes of :func:`electrosense.validation.diagnosis.blind.blind_poses`
for the nominal scene and for each geometric effect built into the scene
(contact impedance as the BEM's boundary condition, the sphere as a mesh, the
other water depth and tank size as the tank mesh, the robot offset as the true
poses). One coarse but fixed discretisation is used for every run (the tank
mesh graded towards the whole trajectory), so that the nominal run is the
diagnosis's baseline and the effect runs differ from it by the physics only.
The output-side effects and the noise are added at test time
(:func:`electrosense.validation.diagnosis.blind.assemble`).

Run: ``python -m electrosense.validation.studies.diagnosis_blind_data [OUT.npz] [--per-pass N]``
(a few minutes on 2 cores).
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

EDGE_LENGTH_M = 0.012
TANK_EDGE_LENGTH_M = 0.02


def bem_world(setup, focus_m, edge_length_m=EDGE_LENGTH_M, tank_edge_length_m=TANK_EDGE_LENGTH_M, progress=True):
    """``world(poses, tank, objects, z_c) -> K`` by the BEM pose sweep, fixed mesh settings.

    Each scene (tank, objects, contact impedance) gets its own
    :class:`electrosense.bem.PoseSweep`, with the tank mesh graded towards ``focus_m`` (the
    whole trajectory, for every scene alike).
    """
    from electrosense.bem import PoseSweep

    def world(poses, tank, objects, z_c):
        sweep = PoseSweep(setup.sensor, tank, tuple(objects), sigma_S_per_m=setup.sigma_S_per_m,
                          contact_impedance_ohm_m2=z_c, edge_length_m=edge_length_m,
                          tank_edge_length_m=tank_edge_length_m, focus_m=focus_m)
        return sweep.conductance(poses, progress=progress).K_S

    return world


def main(argv=None):
    from electrosense.validation.diagnosis.blind import GEOMETRIC_TRUTH, BlindSetup, blind_poses, world_scene
    from electrosense.validation.diagnosis.forward import receiver_currents

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", nargs="?", default="tests/data/diagnosis/bem_worlds.npz", help="output .npz file")
    ap.add_argument("--per-pass", type=int, default=30, help="poses per pass")
    ap.add_argument("--effects", default="none," + ",".join(GEOMETRIC_TRUTH), help="runs to make (comma list)")
    args = ap.parse_args(argv)
    setup = BlindSetup()
    poses, t_s, passes = blind_poses(args.per_pass)
    focus = np.vstack([poses[:, :3], poses[:, :3] + [[0.05, 0.05, 0.0]], poses[:, :3] - [[0.05, 0.05, 0.0]]])
    world = bem_world(setup, focus)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    data = dict(np.load(out)) if out.exists() else {}
    data.update(poses=poses, t_s=t_s, passes=passes)
    for effect in args.effects.split(","):
        t0 = time.perf_counter()
        print(f"{effect}: BEM at {len(poses)} poses", flush=True)
        true_poses, tank, objects, z = world_scene(setup, poses, effect)
        K = world(true_poses, tank, objects, z)
        data[f"K_{effect}"] = K
        data[f"I_{effect}"] = receiver_currents(K, setup.sensor.emitter)
        print(f"  {time.perf_counter() - t0:.0f} s", flush=True)
        np.savez_compressed(out, **data)  # after every run: nothing lost on interruption
    info = {"truth": {k: {kk: (list(vv) if isinstance(vv, tuple) else vv) for kk, vv in v.items()}
                      for k, v in GEOMETRIC_TRUTH.items()},
            "bem": {"edge_length_m": EDGE_LENGTH_M, "tank_edge_length_m": TANK_EDGE_LENGTH_M},
            "sensor": setup.sensor.name, "tank_m": list(setup.tank.size_m), "sigma_S_per_m": setup.sigma_S_per_m}
    out.with_suffix(".json").write_text(json.dumps(info, indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
