"""Blind suite of the gap diagnosis: random effects at random strengths, diagnosed without being told.

Each trial builds bench data from a *world* with one effect (or a pair) at a
strength drawn log-uniformly across a realistic range, adds the bench noise
(0.05 % on currents, 0.1 mm on positions), and runs the diagnosis (effects
evaluated with the calibrated PSM; baseline = the world without effect, as a
perfect simulation of the believed set-up would be; the effect model is the
diagnosis's default: the PSM with spheres at the electrodes plus Kelvin
images for spheres). Printed:

* the confusion matrix: injected effect (rows; for pairs, the stronger one)
  against the first effect chosen (columns);
* the distribution of the held-out shrink (1 - gap after / gap before);
* per effect, the smallest strength found and the strength above which every
  trial was found, with the gap-to-noise ratio there;
* the time of one diagnosis of a 200-pose log against all candidates.

Worlds: ``standin`` (default; the point-electrode model with other electrode
radii and image sums than anything the diagnosis uses: fast) or ``bem`` (the
shipped BEM runs of tests/data/diagnosis/bem_worlds.npz, geometric strengths
fixed, output-side strengths random).

Run: ``python -m electrosense.validation.studies.diagnosis_blind [--trials 60] [--world standin|bem] [--seed 0]``
"""
from __future__ import annotations

import argparse
import time
import warnings
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

EFFECTS = ("conductivity", "temperature_drift", "contact_impedance", "channel_gain", "pose_offset",
           "water_depth", "tank_size", "unmodelled_object", "none")
GEOMETRIC = ("contact_impedance", "pose_offset", "water_depth", "tank_size", "unmodelled_object")


def _loguniform(rng, lo, hi):
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def draw(effect: str, rng) -> tuple[dict, float]:
    """(world/output arguments, strength) for one effect; strength in the effect's natural unit."""
    sign = rng.choice([-1.0, 1.0])
    if effect == "conductivity":
        s = _loguniform(rng, 1e-4, 5e-2)
        return {"conductivity": sign * s}, s
    if effect == "temperature_drift":
        s = _loguniform(rng, 1e-3, 1e-1)  # per hour
        return {"drift_per_hour": sign * s}, s
    if effect == "channel_gain":
        s = _loguniform(rng, 1e-4, 2e-2)
        g = rng.uniform(-1, 1, 3)
        return {"gains": s * g / np.max(np.abs(g))}, s
    if effect == "contact_impedance":
        s = _loguniform(rng, 1e-5, 1e-2)
        return {"geo": {"z_c_ohm_m2": s}}, s
    if effect == "pose_offset":
        s = _loguniform(rng, 2e-4, 1.5e-2)
        a = rng.uniform(0, 2 * np.pi)
        return {"geo": {"dx_m": s * np.cos(a), "dy_m": s * np.sin(a), "dyaw_rad": rng.uniform(-1, 1) * s * 3}}, s
    if effect == "water_depth":
        s = _loguniform(rng, 5e-3, 0.3)
        return {"geo": {"water_depth_m": 1.0 - s}}, s
    if effect == "tank_size":
        s = _loguniform(rng, 2e-3, 5e-2)
        return {"geo": {"Lx_m": 1.0 + sign * s}}, s
    if effect == "unmodelled_object":
        s = _loguniform(rng, 0.01, 0.04)  # radius
        gap = rng.uniform(0.02, 0.12)
        x = rng.uniform(-0.3, 0.3)
        y = sign * (0.01 + s + gap)
        material = rng.choice(["conducting", "insulating"])
        return {"geo": {"centre_m": (x, y, 0.0), "radius_m": s, "material": material}}, s
    return {}, 0.0


def trial(world, setup, poses, t, passes, K0, effects, rng, effect_model, I_cache=None):
    """Make one dataset with ``effects`` (1 or 2 names), diagnose it; return a record."""
    from electrosense.validation.diagnosis.blind import assemble, world_currents
    from electrosense.validation.diagnosis.pipeline import diagnose

    output, geo, strengths = {}, None, {}
    for e in effects:
        if e == "none":
            continue
        args, s = draw(e, rng)
        strengths[e] = s
        if "geo" in args:
            geo = (e, args["geo"])
        else:
            output.update(args)
    if I_cache is not None:  # fixed geometric runs (BEM)
        I = I_cache[geo[0] if geo else "none"]
        if geo:
            strengths[geo[0]] = float("nan")
    else:
        I = world_currents(world, setup, poses, geo[0] if geo else None, geo[1] if geo else None)
    obs = assemble(setup, poses, t, passes, I, rng, **output)
    d = diagnose(obs, K_base=K0, effect_model=effect_model)
    return {"injected": list(effects), "strengths": strengths, "chosen": d.chosen, "gap_before": d.gap_before,
            "gap_after": d.gap_after, "noise": d.noise, "seconds": d.seconds}


def speed(setup, effect_model, world, rng) -> float:
    """Seconds to diagnose a 200-pose log (2 passes of 100) against all candidates."""
    from electrosense.validation.diagnosis.blind import assemble, blind_poses, world_currents
    from electrosense.validation.diagnosis.pipeline import diagnose

    poses, t, passes = blind_poses(100)
    K0 = world(poses, setup.tank, (), None)
    I = world_currents(world, setup, poses, "unmodelled_object")
    obs = assemble(setup, poses, t, passes, I, rng, conductivity=0.02)
    t0 = time.perf_counter()
    d = diagnose(obs, K_base=K0, effect_model=effect_model)
    return time.perf_counter() - t0, d.chosen


def main(argv=None):
    from electrosense.validation.diagnosis.blind import BlindSetup, blind_poses
    from electrosense.validation.diagnosis.forward import PointElectrodeSimulator, geometric_psm
    from electrosense.validation.diagnosis.pipeline import default_effect_model_from

    ap = argparse.ArgumentParser(description="blind suite of the gap diagnosis")
    ap.add_argument("--trials", type=int, default=60, help="number of datasets")
    ap.add_argument("--world", choices=["standin", "bem"], default="standin", help="what makes the data")
    ap.add_argument("--pairs", type=float, default=0.3, help="fraction of trials with two effects")
    ap.add_argument("--seed", type=int, default=0, help="random seed")
    ap.add_argument("--data", default="tests/data/diagnosis/bem_worlds.npz", help="BEM runs (--world bem)")
    ap.add_argument("--effects", default=",".join(EFFECTS), help="effects to inject, in turn (comma list)")
    ap.add_argument("--no-speed", action="store_true", help="skip the 200-pose timing")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    rng = np.random.default_rng(args.seed)
    setup = BlindSetup()
    effect_model = default_effect_model_from(setup.sensor, setup.sigma_S_per_m, geometric_psm(setup.sensor))
    world = PointElectrodeSimulator(setup.sensor, setup.sigma_S_per_m, radius_factor=0.68, shells=3)
    I_cache = None
    if args.world == "bem":
        data = np.load(Path(args.data))
        poses, t, passes = data["poses"], data["t_s"], data["passes"]
        K0 = data["K_none"]
        I_cache = {k[2:]: data[k] for k in data.files if k.startswith("I_")}
    else:
        poses, t, passes = blind_poses(40)
        K0 = world(poses, setup.tank, (), None)

    records = []
    t0 = time.perf_counter()
    order = [e for e in args.effects.split(",") if e]
    unknown = [e for e in order if e not in EFFECTS]
    if unknown:
        ap.error(f"unknown effect(s) {', '.join(unknown)}")
    for i in range(args.trials):
        first = order[i % len(order)]
        effects = [first]
        if first != "none" and rng.uniform() < args.pairs:
            others = [e for e in EFFECTS[:-1] if e != first and not (e in GEOMETRIC and first in GEOMETRIC)]
            effects.append(str(rng.choice(others)))
        records.append(trial(world, setup, poses, t, passes, K0, effects, rng, effect_model, I_cache))
        r = records[-1]
        print(f"{i + 1:3d} {'+'.join(r['injected']):40s} -> {','.join(r['chosen']) or '-':45s} "
              f"gap/noise {r['gap_before'] / r['noise']:8.1f}  shrink {1 - r['gap_after'] / r['gap_before']:6.2f}",
              flush=True)
    report(records)
    print(f"\n{args.trials} trials in {time.perf_counter() - t0:.0f} s")
    if args.no_speed:
        return
    sec, chosen = speed(setup, effect_model, world, rng)
    print(f"speed: 200-pose log (conductivity + object), all candidates: {sec:.1f} s (target < 60 s); chosen {chosen}")


def _strongest(r):
    """The injected effect the confusion matrix is about: the single one, or the one with the larger gap share."""
    inj = [e for e in r["injected"]]
    return inj[0]


def report(records):
    labels = list(EFFECTS)
    conf = defaultdict(Counter)
    for r in records:
        truth = _strongest(r)
        got = r["chosen"][0] if r["chosen"] else "(unexplained)"
        if len(r["injected"]) > 1 and got in r["injected"]:
            got = truth  # a pair is credited when its first choice is one of the injected
        conf[truth][got] += 1
    cols = labels + ["(unexplained)"]
    short = {e: e[:6] for e in cols}
    print("\nconfusion matrix (rows: injected, first of a pair; columns: first chosen, credited if in the pair)")
    print(" " * 20 + " ".join(f"{short[c]:>7s}" for c in cols))
    for e in labels:
        if conf[e]:
            print(f"{e:20s}" + " ".join(f"{conf[e][c]:7d}" for c in cols))
    shrinks = np.array([1 - r["gap_after"] / r["gap_before"] for r in records if r["injected"] != ["none"]])
    strong = np.array([1 - r["gap_after"] / r["gap_before"] for r in records
                       if r["injected"] != ["none"] and r["gap_before"] > 10 * r["noise"]])
    if shrinks.size:
        q = np.percentile(shrinks, [10, 25, 50, 75, 90])
        print(f"\nshrink of the held-out gap, all trials with an effect: p10 {q[0]:.2f} p25 {q[1]:.2f} "
              f"median {q[2]:.2f} p75 {q[3]:.2f} p90 {q[4]:.2f}")
    if strong.size:
        print(f"  trials with gap > 10x noise: {strong.size}, shrink >= 0.8 in {np.mean(strong >= 0.8):.0%}, "
              f"median {np.median(strong):.2f}")
    none = [r for r in records if r["injected"] == ["none"]]
    if none:
        print(f"none: answered 'none' in {sum(r['chosen'] == ['none'] for r in none)}/{len(none)}")
    print("\nsmallest strength found (single-effect trials); strength above which all were found")
    units = {"conductivity": "rel", "temperature_drift": "1/h", "channel_gain": "rel (max)",
             "contact_impedance": "ohm m^2", "pose_offset": "m", "water_depth": "m", "tank_size": "m",
             "unmodelled_object": "m radius"}
    for e in labels[:-1]:
        rs = [r for r in records if r["injected"] == [e] and np.isfinite(r["strengths"].get(e, np.nan))]
        if not rs:
            continue
        found = sorted(r["strengths"][e] for r in rs if r["chosen"][:1] == [e])
        missed = sorted(r["strengths"][e] for r in rs if r["chosen"][:1] != [e])
        smallest = f"{found[0]:.3g}" if found else "-"
        above = max(missed) if missed else 0.0
        all_above = [s for s in found if s > above]
        print(f"  {e:20s} found {len(found)}/{len(rs)}; smallest found {smallest} {units[e]}; "
              f"all found above {min(all_above) if all_above else float('nan'):.3g} {units[e]}")


if __name__ == "__main__":
    main()
