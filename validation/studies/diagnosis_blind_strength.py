"""How strong must an effect be for the diagnosis to name it? Detection rate against signal-to-noise, false alarms.

For each random set-up (:mod:`electrosense.validation.diagnosis.unseen`: 3-6
electrodes, the emitter on any of them, a partly filled box tank, passes at
several headings and depths reaching 1.5 cm of the walls) the world is the BEM
on a finer mesh than the diagnosis's anchors, with the true scene
(:mod:`electrosense.validation.studies.diagnosis_blind_unseen`). Every effect is
injected at several strengths, given as its *signal*: the RMS over the samples
of the relative change of the receiver currents it causes, in units of the
bench noise (0.05 %). A geometric effect is solved by the BEM at a base
strength, its parameters scaled by the ratio of the signals (the offsets,
the wall's and the surface's moves and the contact impedance in proportion,
an object's radius by the cube root), and solved again there: the world
is the BEM's at that strength, never a linear mix of two worlds (near a
wall a few millimetres change the shape of the signal along the pass, which
no model of a smaller move could fit). The signal it really reaches is
printed. An output-side effect (conductivity, drift, channel gains) is set
directly.
Each log is diagnosed with the default ``esense diagnose LOG -o DIR``.

Printed: one line per log (effect, signal/noise, held-out gap over the floor,
what was named, verdict, time), then per effect the rate of naming it first
at each strength, the false-alarm rate on noise-only logs, the smallest
signal named in every log, and the done-when rates of the diagnosis issue.

Run: ``esense study diagnosis_blind_strength [--seeds 0,1] [--strengths 1,2,4] [--none 5] [--per-pass 25]``
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path

import numpy as np

from electrosense.validation.diagnosis.blind import CURRENT_NOISE
from electrosense.validation.studies.diagnosis_blind_unseen import run_cli, world_K

#: effect -> (world effect, world arguments at the base strength, acceptable first names)
GEOMETRIC = {
    "pose_offset": ("pose_offset", {"dx_m": 0.003, "dy_m": -0.002, "dyaw_rad": 0.0}, ("pose_offset",)),
    "heading_offset": ("pose_offset", {"dx_m": 0.0, "dy_m": 0.0, "dyaw_rad": 0.03}, ("pose_offset",)),
    "insulating_object": ("object", {"radius_m": 0.025, "insulating": True}, ("unmodelled_object",)),
    "tank_size": ("tank_size", {"dLx_m": -0.03}, ("tank_size",)),
    "water_depth": ("water_depth", {"d_m": -0.04}, ("water_depth",)),
    "contact_impedance": ("contact_impedance", {"z_c_ohm_m2": 0.002}, ("contact_impedance",)),
}
#: output-side effects: name -> acceptable first names
OUTPUT = {"conductivity": ("conductivity",), "temperature_drift": ("temperature_drift",),
          "channel_gain": ("channel_gain",)}


def scaled_world(world: str, args: dict, factor: float) -> dict:
    """The world arguments of a geometric effect ``factor`` times as strong (module doc)."""
    if world == "object":
        return {**args, "radius_m": args["radius_m"] * factor ** (1 / 3)}
    return {k: (v * factor if isinstance(v, float) else v) for k, v in args.items()}


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def output_arguments(effect: str, signal: float, t_s: np.ndarray, m: int, rng) -> dict:
    """Arguments of :func:`~electrosense.validation.diagnosis.blind.assemble` for an output-side effect whose
    signal (RMS relative change) is ``signal``."""
    if effect == "conductivity":
        return {"conductivity": -signal}
    if effect == "temperature_drift":
        return {"drift_per_hour": signal / _rms((t_s - t_s.mean()) / 3600.0)}
    g = rng.uniform(-1, 1, m)
    return {"gains": signal * g / _rms(g)}


def main(argv=None):
    from electrosense.meshes.sensor import save_sensor
    from electrosense.validation.diagnosis.blind import assemble, write_log
    from electrosense.validation.diagnosis.forward import receiver_currents
    from electrosense.validation.diagnosis.unseen import random_passes, random_setup

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0,1", help="set-up seeds")
    ap.add_argument("--strengths", default="1,2,4", help="signals, in units of the noise")
    ap.add_argument("--effects", default=",".join(list(GEOMETRIC) + list(OUTPUT)))
    ap.add_argument("--none", type=int, default=5, help="noise-only logs per set-up")
    ap.add_argument("--per-pass", type=int, default=25)
    args = ap.parse_args(argv)
    strengths = [float(s) for s in args.strengths.split(",")]
    effects = args.effects.split(",")
    folder = Path(tempfile.mkdtemp(prefix="blind-strength-"))
    cache = Path(os.environ.get("ESENSE_CACHE_DIR", tempfile.gettempdir())) / "blind-worlds"
    rows = []
    for seed in [int(s) for s in args.seeds.split(",")]:
        rng = np.random.default_rng(seed)
        setup = random_setup(rng)
        poses, t, passes = random_passes(setup, rng, 3, args.per_pass)
        m = setup.sensor.n_electrodes - 1
        save_sensor(setup.sensor, folder / f"sensor-{seed}.json")
        e = setup.sensor.emitter
        I0 = receiver_currents(world_K(setup, poses, None, {}, rng, cache), e)
        logs = [("none", 0.0, k, None) for k in range(args.none)]
        logs += [(name, s, 0, None) for name in effects for s in strengths]
        for name, signal, k, _ in logs:
            out_args, I = {}, I0
            acceptable = ("none",)
            if name in GEOMETRIC:
                world, wargs, acceptable = GEOMETRIC[name]
                I1 = receiver_currents(world_K(setup, poses, world, wargs, np.random.default_rng(seed + 1), cache), e)
                base = _rms(I1 / I0 - 1) / CURRENT_NOISE
                I = receiver_currents(world_K(setup, poses, world, scaled_world(world, wargs, signal / base),
                                              np.random.default_rng(seed + 1), cache), e)
            elif name in OUTPUT:
                acceptable = OUTPUT[name]
                out_args = output_arguments(name, signal * CURRENT_NOISE, t, m, np.random.default_rng(seed + 7))
            obs = assemble(setup, poses, t, passes, I, np.random.default_rng(1000 * seed + 17 * k + int(10 * signal)),
                           **out_args)
            obs.meta["sensor"] = f"sensor-{seed}.json"
            log = write_log(obs, folder / f"{name}-{seed}-{signal:g}-{k}.csv")
            d, wall, cpu = run_cli(log, folder / f"diag-{name}-{seed}-{signal:g}-{k}")
            floor = d.get("noise_floor") or d["noise"]
            first = d["chosen"][0] if d["chosen"] else d["verdict"]
            row = {"seed": seed, "n_el": setup.sensor.n_electrodes, "emitter": e, "effect": name, "signal": signal,
                   "signal_reached": _rms(I / I0 - 1) / CURRENT_NOISE if name in GEOMETRIC else signal,
                   "gap_over_floor": d["gap_before"] / floor, "after_over_floor": d["gap_after"] / floor,
                   "shrink": 1 - d["gap_after"] / d["gap_before"], "chosen": d["chosen"], "verdict": d["verdict"],
                   "p_detection": (d.get("detection") or {}).get("p_detection"),
                   "right": first in acceptable, "wall_s": wall, "cpu_s": cpu}
            rows.append(row)
            print(json.dumps({k_: (round(v, 4) if isinstance(v, float) else v) for k_, v in row.items()}), flush=True)
    summarise(rows, strengths)


def summarise(rows: list, strengths: list) -> None:
    """The rates of the module doc."""
    none = [r for r in rows if r["effect"] == "none"]
    if none:
        alarms = sum(not r["right"] for r in none)
        print(f"\nnoise-only logs: {len(none) - alarms}/{len(none)} answered none (false alarms {alarms})")
    print("\nnamed first, by effect and signal (RMS relative change / noise):")
    smallest = {}
    for name in dict.fromkeys(r["effect"] for r in rows if r["effect"] != "none"):
        mine = [r for r in rows if r["effect"] == name]
        cells = []
        for s in strengths:
            at = [r for r in mine if r["signal"] == s]
            if at:
                cells.append(f"{s:g}x: {sum(r['right'] for r in at)}/{len(at)}")
        found = sorted(s for s in strengths if all(r["right"] for r in mine if r["signal"] >= s)
                       and any(r["signal"] == s for r in mine))
        smallest[name] = found[0] if found else None
        print(f"  {name:20s} " + "  ".join(cells) + f"   smallest named from there on: "
              f"{'-' if smallest[name] is None else f'{smallest[name]:g}x'}")
    moved = [r for r in rows if r["effect"] != "none" and r["gap_over_floor"] > 1.3]
    if moved:
        right = sum(r["right"] for r in moved)
        named = [r for r in moved if r["right"]]
        good = sum(r["after_over_floor"] <= 1.2 or r["shrink"] >= 0.8 for r in named)
        print(f"\nlogs whose effect moves the held-out gap beyond 1.3x the floor: named first {right}/{len(moved)} "
              f"({100 * right / len(moved):.0f} %); of those named, gap after within 1.2x the floor or 80 % smaller: "
              f"{good}/{len(named)}")
    walls = [r["wall_s"] for r in rows]
    print(f"diagnosis wall time: first log of a set-up {max(walls):.0f} s at most, median {np.median(walls):.0f} s; "
          f"CPU median {np.median([r['cpu_s'] for r in rows]):.0f} s")


if __name__ == "__main__":
    main()
