"""Real saline tank: the BEM against a measured EIT phantom (noise floor, empty tank held out, balls, diagnosis).

Run: ``esense study real_tank --data FILE.mat|LOG.csv --scene pail.toml -o DIR``.

* The data are read into a transfer log (:mod:`validation.transfer`), written
  to ``DIR/transfer_log.csv`` beside a copy of the scene file.
* Noise floor: reciprocity (drive (a,b)/measure (c,d) against drive
  (c,d)/measure (a,b)) of the reference set-up.
* Empty tank: one BEM solve of the scene gives K of all electrodes and every
  transfer impedance (:mod:`bem.protocol`). What a user cannot know (the
  saline's conductivity times the system's gain: one scale, the two are
  indistinguishable in V/I) is fitted on the even drive patterns and scored
  on the odd ones: ``empty_heldout_rms_rel`` = RMS of (model - measured) /
  measured over the held-out measurements.
* Each ball set-up: difference signal (with ball / without - 1), measured vs
  BEM with the balls where the scene's ``[protocol]`` table says.
* Diagnosis (left out with ``--no-diagnosis``, as ``esense validate`` does):
  candidate effects fitted on the even drives and scored on the odd ones,
  each linear about the BEM: per-channel gains or offsets of the measurement
  system, electrode positions along the wall (one solve's sensitivities, by
  reciprocity), water depth, the tank's shape at the ring (radius; taper of
  the wall; one solve each), current returning through electrodes off the
  ring; contact impedances from the drive pairs' voltages (they cannot
  change a four-electrode transfer impedance). ``diagnosis.chosen`` is the
  candidate with the smallest held-out gap. ``diagnosis.one_geometry``
  asks whether one tank shape explains both the empty tank and the balls:
  the ring radius the empty tank's fit wants against the one at which each
  ball's measured/simulated amplitude is 1.

Nothing is tuned to one file: the ring, the set-ups and the balls come from
the scene's ``[protocol]`` table, the electrodes from its geometry.
"""
from __future__ import annotations

import argparse
import json
import shutil
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from bem.protocol import drive_impedances_ohm, transfer_impedances_ohm
from bem.sensitivity import shift_sensitivities_ohm_per_m
from bem.solve import solve_scene
from meshes.objects import Sphere
from meshes.scene_file import load_scene, load_scene_settings
from meshes.surface_electrodes import DiscElectrode
from validation.transfer import read_transfer_log
from validation.transfer.eit_mat import eit_mat_to_transfer_log


def _K(scene, sigma, bem):
    sol = solve_scene(scene, sigma, **bem)
    return sol.conductance.K_S, sol.info


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def _table(log, setup):
    """Drive pairs, measurement pairs, measured Z (transfer rows) and drive rows of one set-up."""
    t = log.select(setup)
    tr = ~t.is_drive_row
    return t.drive[tr], t.measure[tr], t.Z_ohm[tr], t.drive[~tr], t.Z_ohm[~tr]


def _model(K, drive, meas):
    """Transfer impedance of each row (row-wise pairs)."""
    pairs_d, inv = np.unique(drive, axis=0, return_inverse=True)
    V = transfer_impedances_ohm(K, pairs_d, meas)     # (D, R)
    return V[inv.ravel(), np.arange(len(meas))]


def reciprocity(drive, meas, Z):
    """Relative differences of reciprocal pairs (each pair once)."""
    key = {(tuple(d), tuple(m)): z for d, m, z in zip(drive.tolist(), meas.tolist(), Z)}
    out = []
    for (d, m), z in key.items():
        # reciprocal: drive m (current from m's plus) measured on d; signs follow the pair orders
        for r, sgn in (((m, d), 1.0), (((m[1], m[0]), (d[1], d[0])), 1.0)):
            if r in key and (d, m) < r:
                z2 = sgn * key[r]
                out.append((z - z2) / (0.5 * (z + z2)))
    return np.array(out)


def fit_linear(Zd, columns, folds, gauge=None, ridge=1e-6):
    """Weighted least squares ``Zd ~ sum_k c_k columns[k]`` (relative residuals), fitted and scored per fold.

    ``columns`` (R, P): column 0 is the BEM's Z (its coefficient is the
    scale); the others are effects in ohm (sensitivity times displacement,
    channel indicators...). ``folds``: (R,) fold number of each row (its
    drive pattern's parity); each fold is predicted by the fit on the
    others. ``gauge`` (G, P): rows of constraints ``gauge @ c = 0`` (e.g. a
    rigid rotation of the ring changes nothing). Returns the held-out
    relative residuals (R,) and the coefficients of each fold's fit.
    """
    A = np.asarray(columns, float)
    w = 1.0 / Zd
    P = A.shape[1]
    reg = np.sqrt(ridge) * np.eye(P)[1:] * np.abs(A).max(axis=0)[None, :]
    cons = np.zeros((0, P)) if gauge is None else np.asarray(gauge, float) * np.abs(A).max(axis=0)[None, :]
    res = np.zeros(len(Zd))
    coefs = {}
    for f in np.unique(folds):
        tr = folds != f
        lhs = np.vstack([A[tr] * w[tr, None], reg, 1e3 * cons])
        c = np.linalg.lstsq(lhs, np.r_[np.ones(tr.sum()), np.zeros(len(reg) + len(cons))], rcond=None)[0]
        res[~tr] = (A[~tr] @ c) / Zd[~tr] - 1
        coefs[int(f)] = c
    return res, coefs


def _ring_offsets(drive, meas, proto):
    """(R,) cyclic offset of each measurement pair from its drive pair along the protocol's ring (None: no ring)."""
    ring = [int(e) for e in proto.get("ring", [])]
    if not ring:
        return None
    pos, n = {e: i for i, e in enumerate(ring)}, len(ring)

    def first(pair):      # the pair's first electrode in ring order (cyclic neighbours: the wrap-round pair too)
        i, j = pos[pair[0]], pos[pair[1]]
        return i if (j - i) % n == 1 else j if (i - j) % n == 1 else min(i, j)

    try:
        return np.array([(first(m) - first(d)) % n for d, m in zip(drive.tolist(), meas.tolist())])
    except KeyError:
        return None


def _wall_electrodes(scene):
    """(index, centre, outward normal, azimuthal tangent, radius) of the discs on a cylindrical tank's wall."""
    tank = scene.tank
    if not hasattr(tank, "radius_at"):
        return []
    slope = tank.wall_slope
    out = []
    for i, e in enumerate(scene.electrodes):
        if not isinstance(e, DiscElectrode) or abs(np.hypot(*e.centre_m[:2]) - tank.radius_at(e.centre_m[2])) > 1e-9:
            continue
        phi = np.arctan2(e.centre_m[1], e.centre_m[0])
        normal = np.array([np.cos(phi), np.sin(phi), -slope]) / np.hypot(1.0, slope)   # out of the water
        out.append((i, np.array(e.centre_m), normal, np.array([-np.sin(phi), np.cos(phi), 0.0]), e.radius_m))
    return out


def _reshaped(scene, radius_m=None, floor_radius_m=None):
    """The scene with its cylindrical tank's top/floor radii changed; wall discs follow the wall (same angle, height)."""
    t = scene.tank
    new = replace(t, radius_m=t.radius_m if radius_m is None else radius_m,
                  floor_radius_m=t.floor_radius_m if floor_radius_m is None else floor_radius_m)
    moved = []
    for e in scene.electrodes:
        if isinstance(e, DiscElectrode) and abs(np.hypot(*e.centre_m[:2]) - t.radius_at(e.centre_m[2])) < 1e-9:
            k = float(new.radius_at(e.centre_m[2]) / t.radius_at(e.centre_m[2]))
            e = replace(e, centre_m=(k * e.centre_m[0], k * e.centre_m[1], e.centre_m[2]))
        moved.append(e)
    return replace(scene, tank=new, electrodes=tuple(moved))


def _ring_z(scene, ring):
    """Mean height (m) of the ring's electrodes."""
    return float(np.mean([scene.electrodes[e - 1].centre_m[2] for e in ring]))


def _fit_ball_height(heights, measured, simulated):
    """One height shared by every set-up, from signals simulated at a few heights (quadratic in z).

    Returns the fitted height and, per set-up, ``object_rms_rel`` at the
    first (assumed) height and at the fitted one, with the signal there.
    """
    h = np.asarray(heights, float)
    grid = np.linspace(h.min(), h.max(), 201)

    def at(sig, z):
        S = np.stack(sig)                            # (H, R)
        if len(h) == 1:
            return S[0]
        c = np.polyfit(h, S, min(2, len(h) - 1))     # per entry
        return np.polyval(c, z) if c.ndim == 1 else sum(c[k] * z ** (len(c) - 1 - k) for k in range(len(c)))

    cost = [sum(np.sum((measured[k] - at(simulated[k], z)) ** 2) / np.sum(measured[k] ** 2) for k in measured)
            for z in grid]
    z_fit = float(grid[int(np.argmin(cost))])
    out = {}
    for k in measured:
        s_fit = at(simulated[k], z_fit)
        amp = float(np.sum(s_fit * measured[k]) / np.sum(s_fit ** 2))
        out[k] = {"at_assumed_height": _rms(measured[k] - simulated[k][0]) / _rms(measured[k]),
                  "measured_over_simulated_amplitude": amp,
                  "at_fitted_height": _rms(measured[k] - s_fit) / _rms(measured[k]), "signal": s_fit}
    return z_fit, out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="esense study real_tank", description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True, help="the phantom's .mat file, or a transfer log .csv")
    ap.add_argument("--scene", type=Path, required=True, help="the tank's scene file (TOML) with a [protocol] table")
    ap.add_argument("-o", "--out", type=Path, required=True)
    ap.add_argument("--no-diagnosis", dest="diagnosis", action="store_false",
                    help="only the comparison (noise floor, empty tank, balls): no diagnosis candidates")
    args = ap.parse_args(argv)
    t_start, cpu_start = time.perf_counter(), time.process_time()
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    scene_copy = out / args.scene.name
    if scene_copy.resolve() != args.scene.resolve():
        shutil.copyfile(args.scene, scene_copy)
    if args.data.suffix.lower() == ".mat":
        log_path = eit_mat_to_transfer_log(args.data, out / "transfer_log.csv", scene=args.scene.name)
    else:
        log_path = args.data
    log = read_transfer_log(log_path)
    scene = load_scene(args.scene)
    settings = load_scene_settings(args.scene)
    proto = settings.get("protocol", {})
    sigma = float(settings.get("water", {}).get("sigma_S_per_m", 1.0))
    bem = dict(settings.get("bem", {}))
    ref = str(proto.get("reference", log.setups[0]))
    metrics: dict = {"data": args.data.name, "scene": args.scene.name, "setups": list(log.setups)}

    drive, meas, Zd, ddrive, Vdrive = _table(log, ref)
    rec = reciprocity(drive, meas, Zd)
    metrics["noise_floor"] = {"reciprocity_rms_rel": _rms(rec), "reciprocity_median_abs_rel": float(np.median(np.abs(rec))),
                              "per_measurement_rms_rel": _rms(rec) / np.sqrt(2), "pairs": int(len(rec))}

    t0 = time.perf_counter()
    sol0 = solve_scene(scene, sigma, **bem)
    K0, info0 = sol0.conductance.K_S, sol0.info
    metrics["bem"] = {"triangles": info0["triangles"], "solve_s": time.perf_counter() - t0}
    Zm = _model(K0, drive, meas)
    if np.any(np.sign(Zm) != np.sign(Zd)):
        raise SystemExit(f"{np.sum(np.sign(Zm) != np.sign(Zd))} measurements have the opposite sign to the BEM: "
                         "check the electrode numbering and the log's sign convention")
    Zm, Zd_abs = np.abs(Zm), np.abs(Zd)
    sgn = np.sign(Zd)
    drives = np.unique(drive, axis=0)
    dindex = np.array([np.flatnonzero(np.all(drives == d, axis=1))[0] for d in drive])
    folds = dindex % 2                      # fold 0: even drive patterns (fitted), fold 1: odd (held out)
    held = folds == 1

    def score(cols, gauge=None):
        res, coefs = fit_linear(Zd_abs, np.stack(cols, axis=1), folds, gauge)
        return {"heldout_rms_rel": _rms(res[held]), "twofold_rms_rel": _rms(res),
                "n_parameters": len(cols)}, res, coefs

    base, res0, c0 = score([Zm])
    s = float(c0[1][0])
    gap_before = base["heldout_rms_rel"]
    metrics["empty_heldout_rms_rel"] = gap_before
    metrics["empty_twofold_rms_rel"] = base["twofold_rms_rel"]
    metrics["empty_train_rms_rel"] = _rms(s * Zm[~held] / Zd_abs[~held] - 1)
    metrics["fitted_scale_gain_over_sigma"] = {"scale": s, "sigma_nominal_S_per_m": sigma,
                                               "meaning": "measured V/I = scale * BEM Z at the nominal sigma"}
    off = _ring_offsets(drive, meas, proto)
    if off is not None:
        metrics["empty_rel_error_by_ring_offset"] = {int(o): float(np.mean(s * Zm[off == o] / Zd_abs[off == o] - 1))
                                                     for o in np.unique(off)}

    tank = scene.tank
    ring = [int(e) for e in proto.get("ring", [])]
    floating = {int(e) for e in proto.get("floating", [])}   # electrodes in the water that no cable touches
    shape = None                                             # the radius-scaled scene, for the balls' amplitudes
    resid = {"stated geometry": res0}                        # 2-fold relative residuals of the candidates
    if args.diagnosis:
        # ---- diagnosis candidates: linear effects about the BEM, fitted on even drives, scored on odd ones
        mpairs = np.unique(meas, axis=0)
        mindex = np.array([np.flatnonzero(np.all(mpairs == m, axis=1))[0] for m in meas])
        chan = [(mindex == j).astype(float) for j in range(len(mpairs))]
        cols = {"channel_gains": [Zm * c for c in chan], "channel_offsets": [Zm] + chan,
                "common_offset": [Zm, np.ones(len(Zm))]}
        n_e = K0.shape[0]
        # ground electrode(s) off the ring carrying part of the drive current (sink shared with it)
        others = [e for e in range(1, n_e + 1) if e not in ring and e not in floating]
        for g in others:
            alt = np.abs(_model(K0, np.c_[drive[:, 0], np.full(len(drive), g)], meas))
            cols[f"current_to_electrode_{g}"] = [Zm, alt - Zm]
        # electrode positions along the wall: sensitivities from the one solve (reciprocity)
        t0 = time.perf_counter()
        wall = [w for w in _wall_electrodes(scene) if w[0] + 1 in ring]      # the measured electrodes
        J = None
        if wall:
            idx = np.array([i + 1 for i, *_ in wall])
            Jall = shift_sensitivities_ohm_per_m(sol0, drives, mpairs, idx, [w[1] for w in wall], [w[2] for w in wall],
                                                 [w[3] for w in wall], [w[4] for w in wall])
            J = sgn[:, None] * Jall[dindex, mindex]                       # (R, E) d|Z|/ds, ohm per metre of arc
            cols["electrode_angles"] = [Zm] + list(J.T)
        metrics["bem"]["position_sensitivity_s"] = time.perf_counter() - t0
        # water depth: one more solve (finite difference of a sixth of the depth)
        dZdH = None
        tank = scene.tank
        if hasattr(tank, "water_depth_m"):
            dH = tank.water_depth_m / 6
            t0 = time.perf_counter()
            Kd, _ = _K(replace(scene, tank=replace(tank, water_depth_m=tank.water_depth_m - dH)), sigma, bem)
            dZdH = (Zm - np.abs(_model(Kd, drive, meas))) / dH             # ohm per metre of depth
            metrics["bem"]["depth_solve_s"] = time.perf_counter() - t0
            cols["water_depth"] = [Zm, dZdH]
        # the tank's shape at the ring: radius (both radii scaled) and taper (floor radius alone), one solve each;
        # columns per metre of the RING's radius (taper: per metre of the floor's radius)
        dZdR = dZdF = None
        if hasattr(tank, "radius_at") and ring:
            z_ring = _ring_z(scene, ring)
            R_ring = float(tank.radius_at(z_ring))
            t0 = time.perf_counter()
            f = 0.9
            Kr, _ = _K(_reshaped(scene, f * tank.radius_m, f * tank.floor_radius_m), sigma, bem)
            dZdR = (Zm - np.abs(_model(Kr, drive, meas))) / ((1 - f) * R_ring)
            dF = 0.1 * tank.floor_radius_m
            Kf, _ = _K(_reshaped(scene, floor_radius_m=tank.floor_radius_m - dF), sigma, bem)
            dZdF = (Zm - np.abs(_model(Kf, drive, meas))) / dF
            metrics["bem"]["shape_solves_s"] = time.perf_counter() - t0
            cols["ring_radius"] = [Zm, dZdR]
            shape = {"scene": _reshaped(scene, f * tank.radius_m, f * tank.floor_radius_m), "R_ring_m": R_ring,
                     "R_ring_scaled_m": f * R_ring, "Z": np.abs(_model(Kr, drive, meas))}
            cols["wall_taper"] = [Zm, dZdF]
            cols["ring_radius+wall_taper"] = [Zm, dZdR, dZdF]
            if dZdH is not None:
                cols["ring_radius+water_depth"] = [Zm, dZdR, dZdH]
        if J is not None and dZdH is not None:
            cols["water_depth+electrode_angles"] = [Zm, dZdH] + list(J.T)
            cols["water_depth+electrode_angles+channel_offsets"] = [Zm, dZdH] + list(J.T) + chan
        cands = {}
        for name, cs in cols.items():
            g = None
            if "electrode_angles" in name:
                g = np.zeros((1, len(cs)))
                k0 = 2 if name.startswith("water_depth") else 1
                g[0, k0:k0 + J.shape[1]] = 1.0
            sc, res, coefs = score(cs, g)
            c = coefs[1]
            if name == "water_depth" or name.startswith("water_depth+"):
                sc["depth_change_m"] = float(c[1] / c[0])
            if name.startswith("ring_radius"):
                sc["ring_radius_change_m"] = float(c[1] / c[0])
                sc["ring_radius_m"] = R_ring + float(c[1] / c[0])
            if name.endswith("water_depth") and name != "water_depth":
                sc["depth_change_m"] = float(c[-1] / c[0])
            if "wall_taper" in name:
                k = 1 if name == "wall_taper" else 2
                sc["floor_radius_change_m"] = float(c[k] / c[0])
            if "electrode_angles" in name:
                k0 = 2 if name.startswith("water_depth") else 1
                sc["arc_offsets_mm"] = np.round(1e3 * c[k0:k0 + J.shape[1]] / c[0], 2).tolist()
            if name.startswith("current_to_electrode"):
                sc["fraction"] = float(c[1] / c[0])
            if name == "channel_gains":
                sc["gains_rel"] = np.round(c / np.mean(c), 4).tolist()
            cands[name] = sc
            resid[name] = res
        chosen = min(cands, key=lambda k: cands[k]["heldout_rms_rel"])
        # contact impedances from the drive pairs' voltages (nominal sigma; min-norm over the ring's pairs)
        Zdrive_bem = drive_impedances_ohm(K0, ddrive)
        excess = Vdrive - Zdrive_bem
        A = np.zeros((len(ddrive), n_e))
        A[np.arange(len(ddrive)), ddrive[:, 0] - 1] = 1
        A[np.arange(len(ddrive)), ddrive[:, 1] - 1] = 1
        r_el = np.linalg.lstsq(A, excess, rcond=None)[0]
        areas = np.array([np.pi * e.radius_m ** 2 if isinstance(e, DiscElectrode) else np.nan for e in scene.electrodes])
        contact = {
            "note": "from the drive pairs' voltages; with a current source and floating measurement electrodes they "
                    "cannot change a four-electrode transfer impedance",
            "drive_impedance_measured_ohm": np.round(Vdrive, 2).tolist(),
            "drive_impedance_bem_ohm": np.round(Zdrive_bem, 2).tolist(),
            "z_c_ohm_m2": np.round(r_el * areas[:n_e], 6).tolist()}
        worst = np.argsort(-np.abs(res0[held]))[:4]
        metrics["diagnosis"] = {
            "chosen": chosen, "gap_before": gap_before, "gap_after": cands[chosen]["heldout_rms_rel"],
            "shrink": 1 - cands[chosen]["heldout_rms_rel"] / gap_before, "candidates": cands,
            "contact_impedances": contact,
            "largest_heldout_errors": [{"drive": drive[held][i].tolist(), "measure": meas[held][i].tolist(),
                                        "rel": float(res0[held][i])} for i in worst],
            "remaining": "measurement-specific scatter that no smooth physical effect (depth, electrode angles, ground "
                         "current) nor per-channel gain/offset predicts on held-out drives; reciprocal pairs agree on "
                         "much of it (see noise_floor)"}

    # ---- ball set-ups: the unstated height fitted (one height shared by every set-up) on a few solves
    radius = float(proto.get("ball_radius_m", 0.02))
    zb = float(proto.get("ball_z_m", 0.0))
    setups = [k for k in log.setups if k != ref and k in proto]
    heights = zb + np.array([0.0, 2.0, 4.0]) * radius
    if hasattr(tank, "water_depth_m"):
        heights = heights[heights + radius < tank.free_surface_z_m - 0.5 * radius]
    dm_all, ds_all = {}, {}
    t0 = time.perf_counter()
    for setup in setups:
        d2, m2, Z2, *_ = _table(log, setup)
        if not (np.array_equal(d2, drive) and np.array_equal(m2, meas)):
            raise SystemExit(f"set-up {setup} does not have the reference's measurements")
        dm_all[setup] = Z2 / Zd - 1
        ds_all[setup] = []
        for z in heights:
            balls = tuple(Sphere(centre_m=(float(x), float(y), float(z)), radius_m=radius) for x, y in proto[setup])
            Kb, _ = _K(replace(scene, objects=balls), sigma, bem)
            ds_all[setup].append(np.abs(_model(Kb, drive, meas)) / Zm - 1)
    metrics["bem"]["ball_solves_s"] = time.perf_counter() - t0
    z_fit, ball = _fit_ball_height(heights, dm_all, ds_all)
    metrics["object_rms_rel"] = {k: v["at_fitted_height"] for k, v in ball.items()}
    metrics["object_rms_rel_at_assumed_height"] = {k: v["at_assumed_height"] for k, v in ball.items()}
    metrics["ball_height"] = {"assumed_z_m": zb, "fitted_z_m": z_fit, "scanned_z_m": heights.tolist(),
                              "note": "one height shared by every set-up, scanned above the assumed plane "
                                      "(a ball as far below it gives nearly the same signal)"}
    metrics["ball_height"]["measured_over_simulated_amplitude"] = {
        k: v["measured_over_simulated_amplitude"] for k, v in ball.items()}
    signals = {k: (dm_all[k], v["signal"]) for k, v in ball.items()}
    if shape is not None and setups:
        # ONE geometry for both? the ring radius at which each ball's amplitude matches (assumed height),
        # against the one the empty tank's held-out fit wants
        t0 = time.perf_counter()
        want = {}
        for setup in setups:
            balls = tuple(Sphere(centre_m=(float(x), float(y), float(zb)), radius_m=radius) for x, y in proto[setup])
            Kb, _ = _K(replace(shape["scene"], objects=balls), sigma, bem)
            s1 = np.abs(_model(Kb, drive, meas)) / shape["Z"] - 1
            a0 = float(np.sum(ds_all[setup][0] * dm_all[setup]) / np.sum(ds_all[setup][0] ** 2))
            a1 = float(np.sum(s1 * dm_all[setup]) / np.sum(s1 ** 2))
            want[setup] = shape["R_ring_m"] + (1 - a0) / (a1 - a0) * (shape["R_ring_scaled_m"] - shape["R_ring_m"])
        cands = metrics["diagnosis"]["candidates"]
        metrics["diagnosis"]["one_geometry"] = {
            "ring_radius_m_stated": shape["R_ring_m"],
            "ring_radius_m_for_ball_amplitude": want,
            "ring_radius_m_for_empty_tank": cands["ring_radius"]["ring_radius_m"],
            "empty_heldout_rms_rel_with_ring_radius": cands["ring_radius"]["heldout_rms_rel"],
            "ball_radius_m": radius,
            "note": "radius of the ring's circle at which each ball's measured/simulated amplitude is 1 (linear in "
                    "the radius, ball at the assumed height), against the radius the empty tank's held-out fit "
                    "wants: one tank shape explains both only if they agree"}
        metrics["bem"]["shape_ball_solves_s"] = time.perf_counter() - t0
    metrics["wall_s"] = time.perf_counter() - t_start
    metrics["cpu_s"] = time.process_time() - cpu_start
    (out / "metrics.json").write_text(json.dumps(metrics, indent=1))
    _figures(out, Zd_abs, s * Zm, ~held, rec, signals)
    if off is not None:
        _geometry_figure(out, off, resid, metrics.get("diagnosis", {}).get("one_geometry"))
    _report(out, metrics)
    print(json.dumps({k: metrics[k] for k in ("noise_floor", "empty_heldout_rms_rel", "object_rms_rel")}, indent=1))
    if "diagnosis" in metrics:
        print("diagnosis:", {k: metrics["diagnosis"][k] for k in ("chosen", "gap_before", "gap_after")})
    print("goals: empty_heldout_rms_rel <= 0.045; each object_rms_rel <= 0.15; diagnosis shrink >= 0.5")


def _figures(out, Zd, Zfit, train, rec, signals):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(10, 4.2))
    ax[0].loglog(Zd[train], Zfit[train], "o", ms=3, label="fitted drives (even)")
    ax[0].loglog(Zd[~train], Zfit[~train], "s", ms=3, mfc="none", label="held-out drives (odd)")
    lim = [Zd.min() * 0.8, Zd.max() * 1.2]
    ax[0].plot(lim, lim, "k-", lw=0.8)
    ax[0].set(xlabel="measured V/I (system units)", ylabel="BEM x fitted scale", title="empty tank")
    ax[0].legend()
    ax[1].hist(100 * rec, bins=30)
    ax[1].set(xlabel="reciprocal pair difference (%)", ylabel="pairs", title="measurement's own floor (reciprocity)")
    fig.tight_layout()
    fig.savefig(out / "empty_tank.png", dpi=110)
    plt.close(fig)
    if signals:
        fig, axes = plt.subplots(len(signals), 1, figsize=(10, 2.6 * len(signals)), squeeze=False)
        for a, (name, (dm, ds)) in zip(axes[:, 0], signals.items()):
            a.plot(100 * dm, "k.-", lw=0.6, ms=3, label="measured")
            a.plot(100 * ds, "r.-", lw=0.6, ms=3, label="BEM")
            a.set(ylabel="with/without - 1 (%)", title=f"set-up {name}")
            a.legend(loc="upper left", fontsize=8, ncol=2)
        axes[-1, 0].set_xlabel("measurement (drive-major, drive-touching pairs left out)")
        fig.tight_layout()
        fig.savefig(out / "difference_signals.png", dpi=110)
        plt.close(fig)


def _geometry_figure(out, off, resid, one):
    """Model/measured - 1 by ring offset (held out in turn) for the stated tank and the shape candidates; and the
    ring radius the empty tank and each ball want."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2 if one else 1, figsize=(11 if one else 6, 4.2), squeeze=False)
    a = ax[0, 0]
    offs = np.unique(off)
    for name, mk in (("stated geometry", "ko-"), ("ring_radius", "bs-"), ("wall_taper", "cd--"),
                     ("water_depth", "r^-")):
        if name in resid:
            r = resid[name]
            a.plot(offs, [100 * np.mean(r[off == o]) for o in offs], mk, ms=4, lw=1, label=name.replace("_", " "))
    r0 = resid["stated geometry"]
    a.plot(off + 0.15 * (np.random.default_rng(0).random(len(off)) - 0.5), 100 * r0, ".", color="0.7", ms=2,
           zorder=0, label="each measurement (stated)")
    a.axhline(0, color="k", lw=0.5)
    a.set(xlabel="ring offset of the measurement pair from the drive pair", ylabel="model / measured - 1 (%)",
          title="empty tank: mean by offset, each half held out in turn")
    a.set_ylim(-30, 30)
    a.legend(fontsize=8)
    if one:
        b = ax[0, 1]
        items = [("stated", one["ring_radius_m_stated"]), ("empty tank fit", one["ring_radius_m_for_empty_tank"])] + [
            (f"ball amplitude {k}", v) for k, v in one["ring_radius_m_for_ball_amplitude"].items()]
        colours = ["0.4", "b"] + ["r"] * (len(items) - 2)
        for i, ((_, v), c) in enumerate(zip(items, colours)):
            b.plot(100 * v, i, "o", color=c, ms=8)
            b.annotate(f"{100 * v:.1f}", (100 * v, i), textcoords="offset points", xytext=(8, -4), fontsize=9)
        b.axvline(100 * one["ring_radius_m_stated"], color="0.4", lw=0.8, ls=":")
        b.set_yticks(range(len(items)), [k for k, _ in items])
        b.set_ylim(-0.6, len(items) - 0.4)
        b.set_xlim(100 * min(v for _, v in items) - 1, 100 * max(v for _, v in items) + 1.5)
        b.grid(axis="x", lw=0.3)
        b.set(xlabel="radius of the electrode ring (cm)", title="one tank shape for both? (ring radius wanted)")
    fig.tight_layout()
    fig.savefig(out / "geometry.png", dpi=110)
    plt.close(fig)


def _report(out, m):
    lines = ["# Real tank: BEM against the measured phantom", "",
             (f"Data {m['data']}, scene {m['scene']}, BEM {m['bem']['triangles']} triangles; "
              f"wall {m['wall_s']:.0f} s, CPU {m['cpu_s']:.0f} s."), "",
             (f"- Noise floor (reciprocity): RMS {m['noise_floor']['reciprocity_rms_rel']:.4f} per reciprocal pair, "
              f"~{m['noise_floor']['per_measurement_rms_rel']:.4f} per measurement."),
             f"- Empty tank, held-out drives: empty_heldout_rms_rel = {m['empty_heldout_rms_rel']:.4f} (goal <= 0.045).",
             f"  Both halves held out in turn (2-fold): {m['empty_twofold_rms_rel']:.4f}.",
             f"- Balls: height fitted {m['ball_height']['fitted_z_m']:.3f} m (assumed {m['ball_height']['assumed_z_m']:.3f} m).",
             *[f"- Set-up {k}: object_rms_rel = {v:.3f} at the fitted height, "
               f"{m['object_rms_rel_at_assumed_height'][k]:.3f} at the assumed one (goal <= 0.15); measured/BEM "
               f"amplitude {m['ball_height']['measured_over_simulated_amplitude'][k]:.2f}"
               for k, v in m["object_rms_rel"].items()]]
    if "diagnosis" in m:
        d = m["diagnosis"]
        lines += [(f"- Diagnosis: chosen {d['chosen']}, held-out gap {d['gap_before']:.4f} -> {d['gap_after']:.4f} "
                   f"({100 * d['shrink']:.0f} % shrink; goal >= 50 %)."),
                  *[f"  - {k} ({v['n_parameters']} parameters): held-out {v['heldout_rms_rel']:.4f}, "
                    f"2-fold {v['twofold_rms_rel']:.4f}" for k, v in d["candidates"].items()],
                  f"  - remaining: {d['remaining']}"]
        if "one_geometry" in d:
            g = d["one_geometry"]
            lines += [f"- One tank shape for both? Ring radius stated {100 * g['ring_radius_m_stated']:.1f} cm; the "
                      f"empty tank's held-out fit wants {100 * g['ring_radius_m_for_empty_tank']:.1f} cm (held-out "
                      f"{g['empty_heldout_rms_rel_with_ring_radius']:.4f}); the balls' amplitudes (ball radius "
                      f"{1e3 * g['ball_radius_m']:.2f} mm) want " + ", ".join(
                          f"{k} {100 * v:.1f} cm" for k, v in g["ring_radius_m_for_ball_amplitude"].items()) + "."]
    else:
        lines += ["- Diagnosis: not run (--no-diagnosis)."]
    lines += ["", "![empty tank](empty_tank.png)", "", "![tank shape](geometry.png)", "",
              "![difference signals](difference_signals.png)", ""]
    (out / "report.md").write_text("\n".join(lines))


if __name__ == "__main__":
    main()
