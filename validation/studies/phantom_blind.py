"""Blind files of an EIT phantom's layout: the BEM at a scene the file does not state, an instrument with a known fault.

Run: ``esense study phantom_blind --scene validation/data/pail_1planeB.toml -o DIR [--fault crosstalk|common_mode|none]
[--common-mode C] [--seed N] [--no-bem-table]``.

The ``real_tank`` study is checked on data of a known cause, made the way a
real file differs from its scene: the file holds what a tank measured, not
what its description says.

* **Another scene** (drawn from ``--seed``): the tank's radius (its taper
  kept) within +-3 mm of the stated one, the water's depth within +-6 mm, the
  ring within +-3 mm in height, the tacks' wetted radius 80-100 % of the
  stated one, the balls' radius within +-4 % and their frame shifted by up to
  2 mm; built from the scene file's own objects, not by the fit's code.
* **Another mesh**: the solver's defaults (the finest level of the study's
  ladder, :func:`~electrosense.validation.comparison.study_mesh.mesh_level`),
  graded towards every set-up's balls (one tank mesh for all, as the study), at a geometry the study never
  solves; the study itself takes a coarser level unless the data's noise asks
  for this one.
* **An instrument** read on the file's own layout (``vvX``; the reference's
  current array spelt ``voltRef``, the others ``volts``, as the second Ottawa
  file spells them): a gain per measurement channel (0.5 % RMS), an error per
  row repeated in every set-up (0.8 % RMS: what reciprocity sees as the
  floor), fresh noise per set-up (0.05 %), and the fault:

  - ``crosstalk``: a fixed reading added to each class of (drive, measurement)
    by the parity of their places on the ring, +8 % of the median reading
    on the two mixed classes and -4 % on odd-odd (a multiplexer group's);
  - ``common_mode``: a magnitude demodulator reading ``|Z + c V_cm|``, the
    measurement pair's mean potential against the ring's mean, ``c`` complex
    (``--common-mode``; default ``0.2j``, in quadrature: 3 % RMS on the empty
    tank of ``pail_1planeB.toml``; ``0.4j`` 10 %, the size of the second
    Ottawa file's empty-tank gap);
  - ``none``: the scene's and the channels' errors only.

The study is then run on the file as a user runs it (``esense study
real_tank``, the stated scene file, without its ``[bem]`` table with
``--no-bem-table``), and the goals, the diagnosis's choice and the fault's
size found are printed beside the truth, written to ``DIR/blind.json``.
What the diagnosis is asked to name: ``pair_parity_offsets`` for the
crosstalk, ``common_mode`` for the common mode; with ``none``, the scene fit
should leave the empty tank and the balls at their goals.

These are checks of the engine on data of a known cause; they say nothing of
what a real file holds.
"""
from __future__ import annotations

import argparse
import json
import re
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import scipy.io

from electrosense.bem.protocol import (
    adjacent_protocol,
    drive_impedances_ohm,
    involves_drive,
    node_potentials_V,
    transfer_impedances_ohm,
)
from electrosense.bem.solve import solve_scene
from electrosense.meshes.scene_file import load_scene, load_scene_settings
from electrosense.meshes.scene_mesh import objects_focus_m
from electrosense.meshes.surface_electrodes import DiscElectrode
from electrosense.validation.cli.transfer_logs import run_transfer_comparison
from electrosense.validation.comparison.study_mesh import LEVELS, mesh_level
from electrosense.validation.comparison.transfer import balls_at, stated_balls
from electrosense.validation.comparison.transfer_report import goals_table

#: the source's current (A), as the Ottawa files drive it
CURRENT_A = 4.6e-3
#: instrument: channel gains, a row's error repeated in every set-up, fresh noise per set-up (relative RMS)
CHANNEL_GAIN_RMS, ROW_ERROR_RMS, FRAME_NOISE_RMS = 0.005, 0.008, 0.0005
#: crosstalk per class (even-even, even-odd, odd-even, odd-odd) as a fraction of the median reading
CROSSTALK_OF_MEDIAN = (0.0, 0.08, 0.08, -0.04)
#: the common-mode fraction read by the magnitude demodulator (default: in quadrature)
COMMON_MODE = 0.2j
#: what the diagnosis should name for each fault
NAMED = {"crosstalk": "pair_parity_offsets", "common_mode": "common_mode", "none": None}


def true_scene(scene, protocol: dict, rng) -> tuple:
    """The scene the blind file is made at, its balls per set-up, and the draws (m and relative)."""
    tank = scene.tank
    draw = {"tank_radius_m": rng.uniform(-3e-3, 3e-3), "water_depth_m": rng.uniform(-6e-3, 6e-3),
            "ring_height_m": rng.uniform(-3e-3, 3e-3), "tack_radius_rel": rng.uniform(0.8, 1.0),
            "ball_radius_rel": rng.uniform(0.96, 1.04), "frame_shift_m": rng.uniform(-2e-3, 2e-3, 2).tolist()}
    depth = tank.free_surface_z_m - tank.floor_z_m + draw["water_depth_m"]
    true_tank = replace(tank, radius_m=tank.radius_m + draw["tank_radius_m"], water_depth_m=depth,
                        floor_radius_m=(None if tank.floor_radius_m is None
                                        else tank.floor_radius_m + draw["tank_radius_m"]))
    first = scene.n_sensor_electrodes
    ring = {int(e) - 1 - first for e in protocol["ring"]}
    electrodes = []
    for i, e in enumerate(scene.electrodes):
        if i in ring and isinstance(e, DiscElectrode):
            x, y, z = e.centre_m
            z = z + draw["ring_height_m"]
            r = float(true_tank.radius_at(z)) / np.hypot(x, y)
            e = replace(e, centre_m=(x * r, y * r, z), radius_m=e.radius_m * draw["tack_radius_rel"])
        electrodes.append(e)
    truth = replace(scene, tank=true_tank, electrodes=tuple(electrodes))
    balls = stated_balls(scene, protocol)
    setups = {name: balls_at(np.asarray(positions, float) + draw["frame_shift_m"], balls["z_m"],
                             balls["radius_m"] * draw["ball_radius_rel"])
              for name, positions in protocol.items() if _is_setup(name, positions)}
    return truth, setups, draw


def _is_setup(name: str, value) -> bool:
    """A ``[protocol]`` entry that places balls (a list of (x, y))."""
    return (name not in ("ring", "floating") and isinstance(value, list) and len(value) > 0
            and all(isinstance(p, list) and len(p) == 2 for p in value))


def instrument_reading(K_S, ring, fault: str, gains, row_error, rng, common_mode: complex = COMMON_MODE) -> np.ndarray:
    """(n, n) magnitudes the instrument stores (drive-major), zero where a measurement touches the drive;
    ``common_mode``: the fraction ``c`` of the ``common_mode`` fault (module doc)."""
    d, m = adjacent_protocol(ring)
    n = len(ring)
    Z = transfer_impedances_ohm(K_S, d, m)                             # (n, n) signed, V(m) - V(m + 1) per ampere
    if fault == "common_mode":
        V = node_potentials_V(K_S, d)                                  # (n, E) mean-zero potentials per drive
        idx = np.asarray(ring) - 1
        V = V - V[:, idx].mean(axis=1, keepdims=True)
        Vcm = 0.5 * (V[:, m[:, 0] - 1] + V[:, m[:, 1] - 1])             # (n, n)
        reading = np.abs(Z + common_mode * Vcm)
    else:
        reading = np.abs(Z)
    touched = involves_drive(d, m)
    if fault == "crosstalk":
        k, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        median = np.median(reading[~touched])
        reading = reading + np.asarray(CROSSTALK_OF_MEDIAN)[2 * (k % 2) + j % 2] * median
    reading = reading * (1 + gains[None, :]) * (1 + row_error) * (1 + FRAME_NOISE_RMS * rng.standard_normal((n, n)))
    return np.where(touched, 0.0, reading * CURRENT_A)


def write_blind_file(scene_path: Path, out: Path, fault: str, seed: int, log=print,
                     common_mode: complex = COMMON_MODE) -> tuple[Path, dict]:
    """The blind ``.mat`` of the scene's layout, and the truth it was made at."""
    scene, settings = load_scene(scene_path), load_scene_settings(scene_path)
    protocol = settings["protocol"]
    ring = [int(e) for e in protocol["ring"]]
    rng = np.random.default_rng(seed)
    truth, setups, draw = true_scene(scene, protocol, rng)
    n = len(ring)
    gains = CHANNEL_GAIN_RMS * rng.standard_normal(n)
    row_error = ROW_ERROR_RMS * rng.standard_normal((n, n))
    contact = rng.uniform(4.0, 9.0, n)
    options = mesh_level(truth.tank, LEVELS - 1)
    d, _ = adjacent_protocol(ring)
    data = {"description": f"blind file of {scene_path.name}'s layout made by esense study phantom_blind "
                           f"(fault {fault}, seed {seed})"}
    reference = str(protocol.get("reference", "Ref"))
    # every set-up on one tank mesh graded towards all the balls, as the study solves them: a mesh graded to each
    # set-up's own balls would put the difference of two tank meshes into the file's signals
    focus = objects_focus_m([b for s in setups.values() for b in s])
    if focus is not None:
        options = {**options, "tank_focus_m": focus}
    for name, balls in {reference: (), **setups}.items():
        t0 = time.perf_counter()
        sol = solve_scene(replace(truth, objects=balls), 1.0, **options)
        K = sol.conductance.K_S
        data["vv" + name] = instrument_reading(K, ring, fault, gains, row_error, rng, common_mode).reshape(-1, 1)
        current = "volt" if name == reference else "volts"        # as the second Ottawa file spells them
        data[current + name] = np.full((n, 1), CURRENT_A)            # the source's current, named "volt(s)"
        # the drive pair's voltage: the water's and the pair's contact impedances (4-9x the water's, as on the bench)
        data["curr" + name] = (drive_impedances_ohm(K, d) * CURRENT_A * (1 + contact))[:, None]
        log(f"set-up {name}: {sol.info['triangles']} triangles, {time.perf_counter() - t0:.1f} s")
    path = out / f"blind_{fault}_seed{seed}.mat"
    scipy.io.savemat(path, data)
    return path, {"fault": fault, "seed": seed, "reference": reference, "scene_drawn": draw,
                  "mesh": {k: v for k, v in options.items() if k != "tank_focus_m"},
                  "crosstalk_of_median": list(CROSSTALK_OF_MEDIAN) if fault == "crosstalk" else None,
                  "common_mode": [common_mode.real, common_mode.imag] if fault == "common_mode" else None,
                  "channel_gain_rms": CHANNEL_GAIN_RMS, "row_error_rms": ROW_ERROR_RMS,
                  "frame_noise_rms": FRAME_NOISE_RMS}


def _complex(text: str) -> complex:
    """A complex number as Python writes it (``0.4j``, ``0.05+0.3j``), refused in argparse's words otherwise.

    >>> _complex("0.05+0.3j"), _complex(" 0.4j")
    ((0.05+0.3j), 0.4j)
    """
    try:
        return complex(text.replace(" ", ""))
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a complex number: {text!r} (write e.g. 0.4j or 0.05+0.3j)") from None


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="esense study phantom_blind", description=__doc__.splitlines()[0])
    ap.add_argument("--scene", type=Path, required=True, help="the layout's scene file (TOML) with a [protocol]")
    ap.add_argument("-o", "--out", type=Path, required=True)
    ap.add_argument("--fault", choices=sorted(NAMED), default="crosstalk")
    ap.add_argument("--common-mode", type=_complex, default=COMMON_MODE, metavar="C",
                    help="the common mode's fraction, complex (default 0.2j: in quadrature)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-bem-table", dest="bem_table", action="store_false",
                    help="run the study on the scene file without its [bem] table (the study then picks the mesh)")
    ap.add_argument("--no-scene-fit", dest="scene_fit", action="store_false")
    args = ap.parse_args(argv)
    t0, c0 = time.perf_counter(), time.process_time()
    args.out.mkdir(parents=True, exist_ok=True)
    mat, truth = write_blind_file(args.scene, args.out, args.fault, args.seed, common_mode=args.common_mode)
    scene_copy = args.out / args.scene.name
    text = args.scene.read_text()
    scene_copy.write_text(text if args.bem_table else re.sub(r"(?ms)^\[bem\].*?(?=^\[|\Z)", "", text))
    make_s = time.perf_counter() - t0
    m = run_transfer_comparison(mat, scene_copy, args.out / "study", diagnose=True, scene_fit=args.scene_fit)
    d = m.get("diagnosis", {})
    named = NAMED[args.fault]
    out = {"truth": truth, "make_s": make_s, "study_wall_s": m["wall_s"], "study_cpu_s": m["cpu_s"],
           "wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0,
           "mesh": m["bem"].get("mesh", {}).get("chosen"), "triangles": m["bem"]["triangles"],
           "diagnosis": {k: d.get(k) for k in ("chosen", "verdict", "gap_before", "gap_after")},
           "named": None if named is None else named in str(d.get("chosen", "")),
           "faults_named_falsely": [f for f in NAMED.values() if f and f != named and f in str(d.get("chosen", ""))],
           "found": d.get("engine", {}).get("parameters", {}).get(named) if named else None}
    if args.fault == "crosstalk" and out["found"]:      # as fractions of the median reading, as the truth is given
        vv = scipy.io.loadmat(mat)[f"vv{truth['reference']}"].ravel()
        per_ohm = m["fitted_scale_gain_over_sigma"]["scale"] / (np.median(vv[vv != 0]) / CURRENT_A)
        se = d["engine"]["standard_errors"][named]
        out["found_of_median"] = {k: v * per_ohm for k, v in out["found"].items()}
        out["standard_error_of_median"] = {k: v * per_ohm for k, v in se.items()}
    (args.out / "blind.json").write_text(json.dumps(out, indent=1, default=float))
    print(goals_table(m))
    print(f"truth: {args.fault}; scene drawn {truth['scene_drawn']}")
    print(f"diagnosis: {out['diagnosis']}; the fault named: {out['named']}; found {out['found']}; "
          f"a fault not put in named: {out['faults_named_falsely'] or 'none'}")
    if "found_of_median" in out:
        print("crosstalk found, of the median reading (truth " + " / ".join(f"{c:g}" for c in CROSSTALK_OF_MEDIAN)
              + "): " + " / ".join(f"{v:.4f} +- {out['standard_error_of_median'][k]:.4f}"
                                   for k, v in out["found_of_median"].items()))
    print(f"mesh {out['mesh']} ({out['triangles']} triangles); blind file made in {make_s:.0f} s; "
          f"wall {out['wall_s']:.0f} s, CPU {out['cpu_s']:.0f} s")


if __name__ == "__main__":
    main()
