"""The diagnosis of a transfer log's gap to the BEM: candidate effects, each linear about the one solve.

Each candidate is a set of columns beside the BEM's Z (whose coefficient is
the fitted scale), fitted on the even drive patterns and scored on the odd
ones (:func:`electrosense.validation.comparison.transfer.score_fit`):

* ``channel_gains`` / ``channel_offsets`` / ``common_offset``: the
  measurement system, per measurement pair;
* ``current_to_electrode_G``: part of the drive current returning through an
  electrode off the ring (a ground);
* ``electrode_angles``: each ring electrode moved along the wall, from the
  one solve's sensitivities (reciprocity, :mod:`electrosense.bem.sensitivity`), with the
  rigid rotation of the ring as gauge;
* ``water_depth``, ``ring_radius``, ``wall_taper``: one more solve each
  (finite differences), and combinations of these.

``chosen`` is the candidate with the smallest held-out gap. Contact
impedances come from the drive pairs' own voltages (they cannot change a
four-electrode transfer impedance). :func:`one_geometry` asks whether one
tank shape explains both the empty tank and the balls.

Example
-------
Per-channel gains found on synthetic data (two measurement pairs, 1 % and
-1 %):

>>> drive = np.array([[1, 2], [2, 3], [3, 4], [4, 1]] * 2); meas = np.array([[5, 6]] * 4 + [[6, 7]] * 4)
>>> Zm = np.linspace(1.0, 2.0, 8); Zd = Zm * np.r_[[1.01] * 4, [0.99] * 4]
>>> cols = channel_columns(Zm, meas)
>>> from electrosense.validation.comparison.transfer import drive_folds
>>> cands, _ = score_candidates({"channel_gains": cols["channel_gains"]}, Zd, drive_folds(drive)[2])
>>> cands["channel_gains"]["gains_rel"], cands["channel_gains"]["heldout_rms_rel"] < 1e-5
([1.01, 0.99], True)
"""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from electrosense.bem.protocol import drive_impedances_ohm
from electrosense.bem.sensitivity import shift_sensitivities_ohm_per_m
from electrosense.meshes.surface_electrodes import DiscElectrode
from electrosense.validation.comparison.transfer import (
    balls_at,
    model_transfer_ohm,
    score_fit,
    solved_transfer_ohm,
)

__all__ = [
    "REMAINING",
    "candidate_parameters",
    "channel_columns",
    "contact_impedances",
    "diagnose_transfer",
    "one_geometry",
    "reshaped_tank",
    "score_candidates",
    "wall_discs",
]

#: what the candidates leave, in words (written beside the numbers)
REMAINING = ("measurement-specific scatter that no smooth physical effect (depth, electrode angles, ground "
             "current) nor per-channel gain/offset predicts on held-out drives; reciprocal pairs agree on "
             "much of it (see noise_floor)")


def _on_wall(tank, centre_m) -> bool:
    return abs(np.hypot(*centre_m[:2]) - tank.radius_at(centre_m[2])) < 1e-9


def wall_discs(scene) -> list[tuple]:
    """(index, centre, outward normal, azimuthal tangent, radius) of the discs on a cylindrical tank's wall.

    >>> from electrosense.meshes import Scene; from meshes.cylinder_tank import CylinderTank
    >>> s = Scene(None, tank=CylinderTank(0.1, 0.1), electrodes=[DiscElectrode((0.0, 0.1, 0.0), 0.005)])
    >>> i, c, n, t, a = wall_discs(s)[0]
    >>> i, n.round(6).tolist(), t.round(6).tolist()
    (0, [0.0, 1.0, -0.0], [-1.0, 0.0, 0.0])
    """
    tank = scene.tank
    if not hasattr(tank, "radius_at"):
        return []
    slope = tank.wall_slope
    out = []
    for i, e in enumerate(scene.electrodes):
        if not isinstance(e, DiscElectrode) or not _on_wall(tank, e.centre_m):
            continue
        phi = np.arctan2(e.centre_m[1], e.centre_m[0])
        normal = np.array([np.cos(phi), np.sin(phi), -slope]) / np.hypot(1.0, slope)   # out of the water
        out.append((i, np.array(e.centre_m), normal, np.array([-np.sin(phi), np.cos(phi), 0.0]), e.radius_m))
    return out


def reshaped_tank(scene, radius_m=None, floor_radius_m=None):
    """The scene with its cylindrical tank's top/floor radii changed; wall discs follow the wall (same angle, height).

    >>> from electrosense.meshes import Scene; from meshes.cylinder_tank import CylinderTank
    >>> s = Scene(None, tank=CylinderTank(0.1, 0.1), electrodes=[DiscElectrode((0.1, 0.0, 0.0), 0.005)])
    >>> reshaped_tank(s, 0.09, 0.09).electrodes[0].centre_m
    (0.09, 0.0, 0.0)
    """
    t = scene.tank
    new = replace(t, radius_m=t.radius_m if radius_m is None else radius_m,
                  floor_radius_m=t.floor_radius_m if floor_radius_m is None else floor_radius_m)
    moved = []
    for e in scene.electrodes:
        if isinstance(e, DiscElectrode) and _on_wall(t, e.centre_m):
            k = float(new.radius_at(e.centre_m[2]) / t.radius_at(e.centre_m[2]))
            e = replace(e, centre_m=(k * e.centre_m[0], k * e.centre_m[1], e.centre_m[2]))
        moved.append(e)
    return replace(scene, tank=new, electrodes=tuple(moved))


def channel_columns(Z_model, measure) -> dict:
    """The measurement system's candidates: per-pair gains, per-pair offsets, one common offset.

    >>> cols = channel_columns(np.array([1.0, 2.0, 3.0]), np.array([[1, 2], [2, 3], [1, 2]]))
    >>> [len(c) for c in cols.values()]
    [2, 3, 2]
    """
    mpairs = np.unique(measure, axis=0)
    mindex = np.array([np.flatnonzero(np.all(mpairs == m, axis=1))[0] for m in measure])
    chan = [(mindex == j).astype(float) for j in range(len(mpairs))]
    return {"channel_gains": [Z_model * c for c in chan], "channel_offsets": [Z_model] + chan,
            "common_offset": [Z_model, np.ones(len(Z_model))]}


def _angles_start(name: str) -> int:
    """Index of the first electrode-angle column of a candidate."""
    return 2 if name.startswith("water_depth") else 1


def candidate_parameters(name: str, c, n_angles: int = 0, R_ring_m: float | None = None) -> dict:
    """The physical parameters of a fitted candidate from its coefficients ``c`` (``c[0]``: the scale).

    >>> candidate_parameters("water_depth", np.array([2.0, -0.01]))
    {'depth_change_m': -0.005}
    >>> candidate_parameters("ring_radius", np.array([2.0, 0.02]), R_ring_m=0.15)
    {'ring_radius_change_m': 0.01, 'ring_radius_m': 0.16}
    """
    out = {}
    if name == "water_depth" or name.startswith("water_depth+"):
        out["depth_change_m"] = float(c[1] / c[0])
    if name.startswith("ring_radius"):
        out["ring_radius_change_m"] = float(c[1] / c[0])
        out["ring_radius_m"] = R_ring_m + float(c[1] / c[0])
    if name.endswith("water_depth") and name != "water_depth":
        out["depth_change_m"] = float(c[-1] / c[0])
    if "wall_taper" in name:
        out["floor_radius_change_m"] = float(c[1 if name == "wall_taper" else 2] / c[0])
    if "electrode_angles" in name:
        k0 = _angles_start(name)
        out["arc_offsets_mm"] = np.round(1e3 * c[k0:k0 + n_angles] / c[0], 2).tolist()
    if name.startswith("current_to_electrode"):
        out["fraction"] = float(c[1] / c[0])
    if name == "channel_gains":
        out["gains_rel"] = np.round(c / np.mean(c), 4).tolist()
    return out


def score_candidates(columns: dict, Z_measured, folds, n_angles: int = 0, R_ring_m=None) -> tuple[dict, dict]:
    """Fit and score every candidate; returns {name: scores and parameters} and {name: 2-fold residuals}.

    Candidates with ``electrode_angles`` get the rigid rotation of the ring
    (the sum of the arc offsets) as gauge: it changes nothing.
    """
    cands, resid = {}, {}
    for name, cs in columns.items():
        g = None
        if "electrode_angles" in name:
            g = np.zeros((1, len(cs)))
            k0 = _angles_start(name)
            g[0, k0:k0 + n_angles] = 1.0
        sc, res, coefs = score_fit(Z_measured, cs, folds, g)
        sc.update(candidate_parameters(name, coefs[1], n_angles, R_ring_m))
        cands[name] = sc
        resid[name] = res
    return cands, resid


def contact_impedances(K_S, drive_pairs, drive_Z_ohm, electrodes) -> dict:
    """Contact impedances (ohm m^2) from the drive pairs' own V / I beyond the BEM's (min-norm over the pairs).

    >>> K = np.array([[2.0, -1, -1], [-1, 2, -1], [-1, -1, 2]])
    >>> es = [DiscElectrode((0, 0, 0), 0.01)] * 3
    >>> d = contact_impedances(K, np.array([[1, 2], [2, 3], [3, 1]]), np.array([2.6667, 2.6667, 2.6667]), es)
    >>> d["z_c_ohm_m2"]
    [0.000314, 0.000314, 0.000314]
    """
    Zdrive_bem = drive_impedances_ohm(K_S, drive_pairs)
    n_e = K_S.shape[0]
    A = np.zeros((len(drive_pairs), n_e))
    A[np.arange(len(drive_pairs)), drive_pairs[:, 0] - 1] = 1
    A[np.arange(len(drive_pairs)), drive_pairs[:, 1] - 1] = 1
    r_el = np.linalg.lstsq(A, drive_Z_ohm - Zdrive_bem, rcond=None)[0]
    areas = np.array([np.pi * e.radius_m ** 2 if isinstance(e, DiscElectrode) else np.nan for e in electrodes])
    return {"note": "from the drive pairs' voltages; with a current source and floating measurement electrodes they "
                    "cannot change a four-electrode transfer impedance",
            "drive_impedance_measured_ohm": np.round(drive_Z_ohm, 2).tolist(),
            "drive_impedance_bem_ohm": np.round(Zdrive_bem, 2).tolist(),
            "z_c_ohm_m2": np.round(r_el * areas[:n_e], 6).tolist()}


def diagnose_transfer(comparison, scene, sigma_S_per_m: float, bem_options: dict, protocol: dict):
    """Every candidate about the comparison's BEM solution, the choice, and the contact impedances.

    Parameters
    ----------
    comparison : :class:`electrosense.validation.comparison.transfer.TransferComparison` of the log.
    scene, sigma_S_per_m, bem_options : the scene and the BEM settings of its solve.
    protocol : the scene's ``[protocol]`` table (``ring``, ``floating``).

    Returns
    -------
    ``(diagnosis, residuals, shape, seconds)``: the ``diagnosis`` dict
    (``chosen``, ``gap_before``, ``gap_after``, ``shrink``, ``candidates``...),
    the 2-fold residuals of each candidate (and of the stated geometry), the
    radius-scaled tank for :func:`one_geometry` (None without a ring on a
    cylinder), and the seconds of the extra solves.
    """
    t = comparison.table
    drive, meas = t.drive, t.measure
    Zm, Zd, folds = comparison.Z_model_ohm, comparison.Z_measured_ohm, comparison.folds
    sol0 = comparison.solution
    K0 = sol0.conductance.K_S
    ring = [int(e) for e in protocol.get("ring", [])]
    floating = {int(e) for e in protocol.get("floating", [])}   # electrodes in the water that no cable touches
    seconds = {}
    cols = channel_columns(Zm, meas)
    chan = cols["channel_offsets"][1:]
    # ground electrode(s) off the ring carrying part of the drive current (sink shared with it)
    for g in [e for e in range(1, K0.shape[0] + 1) if e not in ring and e not in floating]:
        alt = np.abs(model_transfer_ohm(K0, np.c_[drive[:, 0], np.full(len(drive), g)], meas))
        cols[f"current_to_electrode_{g}"] = [Zm, alt - Zm]
    # electrode positions along the wall: sensitivities from the one solve (reciprocity)
    t0 = time.perf_counter()
    wall = [w for w in wall_discs(scene) if w[0] + 1 in ring]      # the measured electrodes
    J = None
    if wall:
        mpairs = np.unique(meas, axis=0)
        mindex = np.array([np.flatnonzero(np.all(mpairs == m, axis=1))[0] for m in meas])
        Jall = shift_sensitivities_ohm_per_m(sol0, comparison.drive_pairs, mpairs, np.array([w[0] + 1 for w in wall]),
                                             [w[1] for w in wall], [w[2] for w in wall], [w[3] for w in wall],
                                             [w[4] for w in wall])
        J = comparison.sign[:, None] * Jall[comparison.drive_index, mindex]   # (R, E) d|Z|/ds, ohm per metre of arc
        cols["electrode_angles"] = [Zm] + list(J.T)
    seconds["position_sensitivity_s"] = time.perf_counter() - t0

    def derivative(changed_scene, step):
        return (Zm - solved_transfer_ohm(changed_scene, sigma_S_per_m, bem_options, drive, meas)) / step

    # water depth: one more solve (finite difference of a sixth of the depth)
    dZdH = None
    tank = scene.tank
    if hasattr(tank, "water_depth_m"):
        dH = tank.water_depth_m / 6
        t0 = time.perf_counter()
        dZdH = derivative(replace(scene, tank=replace(tank, water_depth_m=tank.water_depth_m - dH)), dH)
        seconds["depth_solve_s"] = time.perf_counter() - t0
        cols["water_depth"] = [Zm, dZdH]
    # the tank's shape at the ring: radius (both radii scaled) and taper (floor radius alone), one solve each;
    # columns per metre of the RING's radius (taper: per metre of the floor's radius)
    shape, R_ring = None, None
    if hasattr(tank, "radius_at") and ring:
        R_ring = float(tank.radius_at(float(np.mean([scene.electrodes[e - 1].centre_m[2] for e in ring]))))
        t0 = time.perf_counter()
        f = 0.9
        scaled = reshaped_tank(scene, f * tank.radius_m, f * tank.floor_radius_m)
        Z_scaled = solved_transfer_ohm(scaled, sigma_S_per_m, bem_options, drive, meas)
        dZdR = (Zm - Z_scaled) / ((1 - f) * R_ring)
        dF = 0.1 * tank.floor_radius_m
        dZdF = derivative(reshaped_tank(scene, floor_radius_m=tank.floor_radius_m - dF), dF)
        seconds["shape_solves_s"] = time.perf_counter() - t0
        cols["ring_radius"] = [Zm, dZdR]
        shape = {"scene": scaled, "R_ring_m": R_ring, "R_ring_scaled_m": f * R_ring, "Z": Z_scaled}
        cols["wall_taper"] = [Zm, dZdF]
        cols["ring_radius+wall_taper"] = [Zm, dZdR, dZdF]
        if dZdH is not None:
            cols["ring_radius+water_depth"] = [Zm, dZdR, dZdH]
    if J is not None and dZdH is not None:
        cols["water_depth+electrode_angles"] = [Zm, dZdH] + list(J.T)
        cols["water_depth+electrode_angles+channel_offsets"] = [Zm, dZdH] + list(J.T) + chan
    cands, resid = score_candidates(cols, Zd, folds, 0 if J is None else J.shape[1], R_ring)
    resid = {"stated geometry": comparison.residual, **resid}
    chosen = min(cands, key=lambda k: cands[k]["heldout_rms_rel"])
    gap_before = comparison.metrics["empty_heldout_rms_rel"]
    held = comparison.held_out
    r0 = comparison.residual[held]
    worst = np.argsort(-np.abs(r0))[:4]
    diagnosis = {
        "chosen": chosen, "gap_before": gap_before, "gap_after": cands[chosen]["heldout_rms_rel"],
        "shrink": 1 - cands[chosen]["heldout_rms_rel"] / gap_before, "candidates": cands,
        "contact_impedances": contact_impedances(K0, t.drive_pairs, t.drive_Z_ohm, scene.electrodes),
        "largest_heldout_errors": [{"drive": drive[held][i].tolist(), "measure": meas[held][i].tolist(),
                                    "rel": float(r0[i])} for i in worst],
        "remaining": REMAINING}
    return diagnosis, resid, shape, seconds


def one_geometry(comparison, shape: dict, ring_radius_candidate: dict, sigma_S_per_m: float, bem_options: dict,
                 protocol: dict) -> dict:
    """Does ONE tank shape explain both the empty tank and the balls?

    For each ball set-up of ``comparison``, the ring radius at which its
    measured/simulated amplitude is 1 (linear in the radius between the
    stated tank and ``shape``'s scaled one, ball at the assumed height: one
    more solve each), against the radius the empty tank's held-out fit wants
    (``ring_radius_candidate``, from :func:`diagnose_transfer`).
    """
    t = comparison.table
    radius = float(protocol.get("ball_radius_m", 0.02))
    zb = float(protocol.get("ball_z_m", 0.0))
    want = {}
    for setup, dm in comparison.measured_signals.items():
        balls = balls_at(protocol[setup], zb, radius)
        s1 = solved_transfer_ohm(replace(shape["scene"], objects=balls), sigma_S_per_m, bem_options, t.drive,
                                 t.measure) / shape["Z"] - 1
        s0 = comparison.simulated_signals[setup][0]
        a0 = float(np.sum(s0 * dm) / np.sum(s0 ** 2))
        a1 = float(np.sum(s1 * dm) / np.sum(s1 ** 2))
        want[setup] = shape["R_ring_m"] + (1 - a0) / (a1 - a0) * (shape["R_ring_scaled_m"] - shape["R_ring_m"])
    return {"ring_radius_m_stated": shape["R_ring_m"],
            "ring_radius_m_for_ball_amplitude": want,
            "ring_radius_m_for_empty_tank": ring_radius_candidate["ring_radius_m"],
            "empty_heldout_rms_rel_with_ring_radius": ring_radius_candidate["heldout_rms_rel"],
            "ball_radius_m": radius,
            "note": "radius of the ring's circle at which each ball's measured/simulated amplitude is 1 (linear in "
                    "the radius, ball at the assumed height), against the radius the empty tank's held-out fit "
                    "wants: one tank shape explains both only if they agree"}
