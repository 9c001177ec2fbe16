"""A transfer log against the BEM of its scene: noise floor, the empty tank held out, each object's signal.

The measured side is a transfer log (:mod:`electrosense.validation.bench.transfer`): for each
set-up, four-electrode transfer impedances ``Z = V / I`` and the drive pairs'
own voltages. The model side is one BEM solve of the scene: the conductance
matrix K of all its electrodes gives every transfer impedance
(:mod:`electrosense.bem.protocol`).

* Noise floor (:func:`reciprocity_rel`): drive (a, b) / measure (c, d)
  against drive (c, d) / measure (a, b) of the reference set-up; whether a
  gain per pair of the measurement system (driving, measuring) explains it
  (:func:`reciprocity_after_pair_gains`).
* Empty tank (:func:`compare_empty_tank`): what a user cannot know (the
  saline's conductivity times the system's gain: one scale) is fitted on the
  even drive patterns and scored on the odd ones (:func:`drive_folds`,
  :func:`fit_linear`): ``empty_heldout_rms_rel``; both halves held out in
  turn: ``empty_twofold_rms_rel``.
* Objects (:func:`compare_objects`): each set-up's difference signal (with
  the balls / without - 1), measured against the BEM's with the balls where
  the scene's ``[protocol]`` table says, their unstated height fitted (one
  height shared by every set-up): ``object_rms_rel``; for a set-up whose scene and balls share a symmetry
  (a rotation or a mirror), the least misfit any scene with that symmetry can reach
  (:mod:`~electrosense.validation.comparison.symmetry`): ``object_symmetric_floor``; the same for the empty
  tank's ``log |Z|`` read through one gain: ``empty_symmetric_floor``.

Nothing is tuned to one file: the ring, the set-ups and the balls come from
the scene's ``[protocol]`` table, the electrodes from its geometry. The
diagnosis of what remains is :mod:`electrosense.validation.diagnosis.transfer`; figures
and report :mod:`electrosense.validation.comparison.transfer_report`.

Example
-------
The fit of one scale on even drives, scored on odd ones (data 2 % above a
model that is exact in shape):

>>> Zm = np.array([1.0, 2.0, 3.0, 4.0])
>>> res, coefs = fit_linear(1.02 * Zm, Zm[:, None], folds=np.array([0, 1, 0, 1]))
>>> np.round(coefs[1], 6).tolist(), float(np.abs(res).max()) < 1e-9
([1.02], True)
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.stats

from electrosense.bem.protocol import transfer_impedances_ohm
from electrosense.bem.solve import solve_scene
from electrosense.meshes.objects import Sphere
from electrosense.meshes.scene_mesh import objects_focus_m
from electrosense.validation.comparison.metrics import error_summary
from electrosense.validation.comparison.symmetry import scene_symmetries, symmetric_floor

__all__ = [
    "SetupTable",
    "TransferComparison",
    "TransferMismatchError",
    "ball_heights_m",
    "stated_balls",
    "balls_at",
    "compare_empty_tank",
    "compare_objects",
    "compare_transfer_log",
    "drive_folds",
    "fit_ball_height",
    "fit_linear",
    "mean_by_offset",
    "measurement_noise",
    "model_transfer_ohm",
    "noise_floor",
    "pair_parity_classes",
    "reciprocal_pairs",
    "reciprocity_after_pair_gains",
    "reciprocity_after_parity_offsets",
    "reciprocity_rel",
    "ring_offsets",
    "ring_pair_places",
    "score_fit",
    "setup_table",
    "signal_floor",
    "solved_transfer_ohm",
]


class TransferMismatchError(ValueError):
    """The log and the scene do not describe the same measurement (signs, set-ups)."""


def _rms(x) -> float:
    return error_summary(x)["rms"]


@dataclass(frozen=True)
class SetupTable:
    """One set-up of a transfer log: its transfer rows (row-wise pairs, 1-based) and its drive rows.

    ``drive`` (R, 2), ``measure`` (R, 2), ``Z_ohm`` (R,) of the four-electrode
    rows; ``drive_pairs`` (D, 2) and ``drive_Z_ohm`` (D,) of the rows whose
    measurement pair is the drive pair (the drive pair's own V / I).
    """

    drive: np.ndarray
    measure: np.ndarray
    Z_ohm: np.ndarray
    drive_pairs: np.ndarray
    drive_Z_ohm: np.ndarray


def setup_table(log, setup: str) -> SetupTable:
    """The :class:`SetupTable` of ``setup`` in a :class:`~validation.bench.transfer.TransferLog`."""
    t = log.select(setup)
    tr = ~t.is_drive_row
    return SetupTable(t.drive[tr], t.measure[tr], t.Z_ohm[tr], t.drive[~tr], t.Z_ohm[~tr])


def model_transfer_ohm(K_S, drive, measure) -> np.ndarray:
    """Transfer impedance (ohm) of each row: drive pair ``drive[r]``, measurement pair ``measure[r]`` (1-based).

    >>> K = np.array([[2.0, -1, -1], [-1, 2, -1], [-1, -1, 2]])     # three electrodes, 1 S between each two
    >>> model_transfer_ohm(K, np.array([[1, 2], [1, 2]]), np.array([[1, 2], [1, 3]])).round(4).tolist()
    [0.6667, 0.3333]
    """
    pairs_d, inv = np.unique(drive, axis=0, return_inverse=True)
    V = transfer_impedances_ohm(K_S, pairs_d, measure)     # (D, R)
    return V[inv.ravel(), np.arange(len(measure))]


def solved_transfer_ohm(scene, sigma_S_per_m: float, bem_options: dict, drive, measure) -> np.ndarray:
    """|transfer impedance| (ohm) of each row, from one BEM solve of ``scene``."""
    K = solve_scene(scene, sigma_S_per_m, **bem_options).conductance.K_S
    return np.abs(model_transfer_ohm(K, drive, measure))


def reciprocal_pairs(drive, measure) -> tuple[np.ndarray, np.ndarray]:
    """Row indices ``(i, j)`` of the reciprocal pairs (drive and measurement swapped, signs followed), each once.

    >>> d = np.array([[1, 2], [4, 3], [1, 2]]); m = np.array([[4, 3], [1, 2], [5, 6]])
    >>> [x.tolist() for x in reciprocal_pairs(d, m)]
    [[0], [1]]
    """
    row = {(tuple(d), tuple(m)): r for r, (d, m) in enumerate(zip(drive.tolist(), measure.tolist()))}
    i, j = [], []
    for (d, m), r in row.items():
        # reciprocal: drive m (current from m's plus) measured on d; signs follow the pair orders
        for other in ((m, d), ((m[1], m[0]), (d[1], d[0]))):
            if other in row and (d, m) < other:
                i.append(r)
                j.append(row[other])
    return np.array(i, dtype=np.int64), np.array(j, dtype=np.int64)


def reciprocity_rel(drive, measure, Z_ohm) -> np.ndarray:
    """Relative differences ``(z - z') / mean`` of reciprocal pairs (drive and measurement swapped), each pair once.

    >>> d = np.array([[1, 2], [4, 3]]); m = np.array([[4, 3], [1, 2]])
    >>> reciprocity_rel(d, m, np.array([1.02, 0.98])).round(4).tolist()
    [0.04]
    """
    i, j = reciprocal_pairs(drive, measure)
    z, z2 = np.asarray(Z_ohm, float)[i], np.asarray(Z_ohm, float)[j]
    return (z - z2) / (0.5 * (z + z2))


def reciprocity_after_pair_gains(drive, measure, Z_ohm) -> dict:
    """Does a gain per electrode pair, one when it drives and another when it measures, explain the reciprocity error?

    A measurement system whose pair ``p`` has gain ``g_d(p)`` driving and
    ``g_m(p)`` measuring gives ``log z - log z' = h(a, b) - h(c, d)`` on the
    reciprocal pairs, ``h = log(g_d / g_m)``: one number per pair, fitted by
    least squares. ``rms_rel_after`` near 0 says the channels are what
    breaks reciprocity (and modelling them restores it); near
    ``rms_rel_before`` says they are not.

    >>> d = np.array([[1, 2], [3, 4], [1, 2]]); m = np.array([[3, 4], [1, 2], [5, 6]])
    >>> out = reciprocity_after_pair_gains(d, m, np.array([1.05, 0.95, 1.0]))
    >>> round(out["rms_rel_before"], 3), out["rms_rel_after"] < 1e-12
    (0.1, True)
    """
    i, j = reciprocal_pairs(drive, measure)
    Z = np.abs(np.asarray(Z_ohm, float))
    y = np.log(Z[i] / Z[j])
    key = [tuple(sorted(p)) for p in np.asarray(drive).tolist() + np.asarray(measure).tolist()]
    pairs = sorted(set(key))
    col = {p: k for k, p in enumerate(pairs)}
    n = len(drive)
    A = np.zeros((len(y), len(pairs)))
    np.add.at(A, (np.arange(len(y)), [col[key[r]] for r in i]), 1.0)        # drive of row i
    np.add.at(A, (np.arange(len(y)), [col[key[n + r]] for r in i]), -1.0)   # its measurement
    h = np.linalg.lstsq(A, y, rcond=None)[0]
    # (z - z') / mean from log(z / z') = 2 tanh(log / 2): the measure of reciprocity_rel
    return {"rms_rel_before": _rms(2 * np.tanh(y / 2)), "rms_rel_after": _rms(2 * np.tanh((y - A @ h) / 2)),
            "pairs": len(y), "parameters": int(np.linalg.matrix_rank(A)) if len(y) else 0}


def noise_floor(rec) -> dict:
    """The measurement's own floor from the reciprocal pairs' relative differences ``rec``.

    >>> round(float(noise_floor(np.array([0.03, -0.03]))["per_measurement_rms_rel"]), 4)
    0.0212
    """
    return {"reciprocity_rms_rel": _rms(rec), "reciprocity_median_abs_rel": float(np.median(np.abs(rec))),
            "per_measurement_rms_rel": _rms(rec) / np.sqrt(2), "pairs": len(rec)}


#: the false-alarm rate at which an instrument's non-reciprocal part is taken out of the reciprocity floor (the
#: diagnosis's detection test uses the same)
RECIPROCITY_ALPHA = 0.01


def measurement_noise(drive, measure, Z_ohm, ring=()) -> dict:
    """The measurement's noise from its reciprocal pairs: the floor (:func:`noise_floor`), what a gain per electrode
    pair (:func:`reciprocity_after_pair_gains`) and a crosstalk differing between the mixed multiplexer classes
    (:func:`reciprocity_after_parity_offsets`) explain of it, and the noise per measurement a fit assumes:
    ``fit_noise_rel``, the floor, or where that crosstalk is significant at :data:`RECIPROCITY_ALPHA` the floor it
    leaves (an instrument's error that breaks reciprocity is not noise); ``fit_noise_from`` says which.

    >>> d = np.array([[1, 2], [4, 5]]); m = np.array([[4, 5], [1, 2]])
    >>> out = measurement_noise(d, m, np.array([1.02, 0.98]))
    >>> round(float(out["per_measurement_rms_rel"]), 4), out["fit_noise_from"]
    (0.0283, 'the reciprocity floor')
    """
    rec = reciprocity_rel(drive, measure, Z_ohm)
    floor = noise_floor(rec)
    out = {**floor, "pair_gains": reciprocity_after_pair_gains(drive, measure, Z_ohm),
           "fit_noise_rel": floor["per_measurement_rms_rel"], "fit_noise_from": "the reciprocity floor"}
    crosstalk = reciprocity_after_parity_offsets(drive, measure, Z_ohm, list(ring)) if len(ring) else {}
    if crosstalk:
        out["parity_offsets"] = crosstalk
        if crosstalk["p_value"] < RECIPROCITY_ALPHA:
            out["fit_noise_rel"] = crosstalk["rms_rel_after"] / np.sqrt(2)
            out["fit_noise_from"] = ("the reciprocity floor less the mixed multiplexer classes' crosstalk "
                                     f"difference (p = {crosstalk['p_value']:.1e})")
    return out


def drive_folds(drive) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distinct drive pairs (D, 2), each row's index among them, and its fold: 0 even drive patterns, 1 odd.

    >>> pairs, index, folds = drive_folds(np.array([[2, 3], [1, 2], [1, 2], [3, 4]]))
    >>> index.tolist(), folds.tolist()
    ([1, 0, 0, 2], [1, 0, 0, 0])
    """
    drives = np.unique(drive, axis=0)
    dindex = np.array([np.flatnonzero(np.all(drives == d, axis=1))[0] for d in drive])
    return drives, dindex, dindex % 2


def fit_linear(Zd, columns, folds, gauge=None, ridge=1e-6):
    """Weighted least squares ``Zd ~ sum_k c_k columns[k]`` (relative residuals), fitted and scored per fold.

    Parameters
    ----------
    Zd : (R,) measured |Z| (ohm, or the system's units).
    columns : (R, P); column 0 is the BEM's Z (its coefficient is the scale),
        the others effects in ohm (sensitivity times displacement, channel
        indicators...).
    folds : (R,) fold number of each row; each fold is predicted by the fit
        on the others.
    gauge : (G, P) rows of constraints ``gauge @ c = 0`` (e.g. a rigid
        rotation of the ring changes nothing), or None.
    ridge : relative Tikhonov weight on the effects (not on the scale).

    Returns
    -------
    The held-out relative residuals (R,) and ``{fold: coefficients}`` of each
    fold's fit (the fit that holds that fold out); the coefficients'
    standard errors are ``{"se": {fold: se}}`` in the same dict: the
    covariance of the weighted least squares with the training residuals'
    own scatter as the noise (relative, independent from row to row).

    >>> Zm = np.array([1.0, 2.0, 3.0, 4.0]); one = np.ones(4)
    >>> res, c = fit_linear(2 * Zm + 0.5, np.c_[Zm, one], np.array([0, 1, 0, 1]))
    >>> np.round(c[0], 3).tolist(), bool(np.abs(res).max() < 1e-4)     # the ridge keeps effects a hair small
    ([2.0, 0.5], True)
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
        r = A[tr] @ c / Zd[tr] - 1
        noise2 = float(r @ r) / max(int(tr.sum()) - P + len(cons), 1)
        coefs.setdefault("se", {})[int(f)] = np.sqrt(np.clip(np.diag(np.linalg.pinv(lhs.T @ lhs)) * noise2, 0, None))
    return res, coefs


def score_fit(Zd, columns, folds, gauge=None) -> tuple[dict, np.ndarray, dict]:
    """:func:`fit_linear` of the columns (a list of (R,) arrays) and its scores: held out (fold 1) and 2-fold RMS.

    >>> Zm = np.array([1.0, 2.0, 3.0, 4.0])
    >>> sc, res, c = score_fit(1.1 * Zm, [Zm], np.array([0, 1, 0, 1]))
    >>> sc["n_parameters"], sc["heldout_rms_rel"] < 1e-9
    (1, True)
    """
    res, coefs = fit_linear(Zd, np.stack(columns, axis=1), folds, gauge)
    return {"heldout_rms_rel": _rms(res[folds == 1]), "twofold_rms_rel": _rms(res),
            "n_parameters": len(columns)}, res, coefs


def ring_pair_places(pairs, ring) -> np.ndarray | None:
    """(R,) place along ``ring`` of each electrode pair's first electrode (cyclic neighbours: the wrap-round pair's
    is the last place); None when a pair is off the ring or there is no ring.

    >>> ring_pair_places(np.array([[1, 2], [4, 3], [4, 1]]), [1, 2, 3, 4]).tolist()
    [0, 2, 3]
    """
    ring = [int(e) for e in ring]
    if not ring:
        return None
    pos, n = {e: i for i, e in enumerate(ring)}, len(ring)

    def first(pair):
        i, j = pos[pair[0]], pos[pair[1]]
        return i if (j - i) % n == 1 else j if (i - j) % n == 1 else min(i, j)

    try:
        return np.array([first(p) for p in np.asarray(pairs).tolist()])
    except KeyError:
        return None


def pair_parity_classes(drive, measure, ring) -> np.ndarray | None:
    """(R,) class of each row by the parity of its pairs' places along ``ring``
    (:func:`ring_pair_places`): ``2 * parity(drive pair) + parity(measurement pair)``, numbered as
    ``PARITY_CLASSES`` names them (a multiplexer that routes odd and even pairs through different groups);
    None when a pair is off the ring.

    >>> pair_parity_classes(np.array([[1, 2], [2, 3]]), np.array([[4, 3], [1, 4]]), [1, 2, 3, 4]).tolist()
    [0, 3]
    """
    d, m = ring_pair_places(drive, ring), ring_pair_places(measure, ring)
    return None if d is None or m is None else 2 * (d % 2) + m % 2


def reciprocity_after_parity_offsets(drive, measure, Z_ohm, ring) -> dict:
    """Does a crosstalk that differs between the two mixed multiplexer classes explain the reciprocity error?

    A fixed reading ``c`` added to each class of (drive pair, measurement pair)
    (:func:`pair_parity_classes`) moves a row of the even-odd class and its
    reciprocal (odd-even) apart by ``c_eo - c_oe``: ``z - z' = +-(c_eo - c_oe)``, one
    number, fitted by least squares on the relative differences. The part of the
    reciprocity error that is this instrument's, not noise: ``p_value`` of the F test (one
    parameter), ``rms_rel_after`` the error left (scaled for the parameter fitted),
    ``difference_ohm`` and ``standard_error_ohm``. Empty without a ring or mixed reciprocal pairs.

    >>> d = np.array([[1, 2], [3, 4], [1, 2], [4, 5]]); m = np.array([[3, 4], [1, 2], [4, 5], [1, 2]])
    >>> out = reciprocity_after_parity_offsets(d, m, np.array([1.0, 1.0, 1.02, 0.98]), [1, 2, 3, 4, 5, 6])
    >>> round(out["difference_ohm"], 4), out["pairs"]
    (0.04, 2)
    """
    i, j = reciprocal_pairs(drive, measure)
    cls = pair_parity_classes(drive, measure, ring)
    if cls is None or not len(i):
        return {}
    s = np.where(cls[i] == 1, 1.0, np.where(cls[i] == 2, -1.0, 0.0))       # row i even-odd: +; odd-even: -
    if not np.any(s):
        return {}
    Z = np.abs(np.asarray(Z_ohm, float))
    mean = 0.5 * (Z[i] + Z[j])
    y, x = (Z[i] - Z[j]) / mean, s / mean                                  # relative: y = c x + noise
    c = float(x @ y / (x @ x))
    n = len(y)
    rss0, rss1 = float(y @ y), float((y - c * x) @ (y - c * x))
    dof = max(n - 1, 1)
    F = (rss0 - rss1) / max(rss1 / dof, np.finfo(float).tiny)
    return {"difference_ohm": c, "standard_error_ohm": float(np.sqrt(rss1 / dof / (x @ x))),
            "rms_rel_before": float(np.sqrt(rss0 / n)), "rms_rel_after": float(np.sqrt(rss1 / dof)),
            "p_value": float(scipy.stats.f.sf(F, 1, dof)), "pairs": n}


def ring_offsets(drive, measure, ring) -> np.ndarray | None:
    """(R,) cyclic offset of each measurement pair from its drive pair along ``ring`` (None: no ring, or off it).

    >>> ring_offsets(np.array([[1, 2], [1, 2]]), np.array([[4, 3], [1, 4]]), [1, 2, 3, 4]).tolist()
    [2, 3]
    """
    d, m = ring_pair_places(drive, ring), ring_pair_places(measure, ring)
    return None if d is None or m is None else (m - d) % len(ring)


def signal_floor(drive, measure, Z_ref, Z_setup) -> float:
    """Per-measurement noise of a set-up's difference signal ``Z_setup / Z_ref - 1``, from its reciprocity (the
    change ``Z_setup - Z_ref`` of reciprocal pairs, over the reference's mean, divided by sqrt 2).

    >>> d = np.array([[1, 2], [3, 4]]); m = np.array([[3, 4], [1, 2]])
    >>> round(signal_floor(d, m, np.array([1.0, 1.0]), np.array([1.03, 1.01])), 4)
    0.0141
    """
    i, j = reciprocal_pairs(drive, measure)
    dZ = np.asarray(Z_setup, float) - np.asarray(Z_ref, float)
    rel = (dZ[i] - dZ[j]) / (0.5 * (np.abs(Z_ref[i]) + np.abs(Z_ref[j])))
    return float(np.sqrt(np.mean(rel ** 2)) / np.sqrt(2)) if len(rel) else float("nan")


def mean_by_offset(offsets, values) -> dict:
    """Mean of ``values`` over the rows of each ring offset.

    >>> mean_by_offset(np.array([2, 2, 3]), np.array([0.1, 0.3, -0.2]))
    {2: 0.2, 3: -0.2}
    """
    return {int(o): float(np.mean(values[offsets == o])) for o in np.unique(offsets)}


def ball_heights_m(z_m: float, radius_m: float, tank) -> np.ndarray:
    """Heights scanned for balls of unstated height: the stated plane and 2, 4 radii above, under the water's surface.

    >>> ball_heights_m(0.0, 0.01, None).tolist()
    [0.0, 0.02, 0.04]
    """
    heights = z_m + np.array([0.0, 2.0, 4.0]) * radius_m
    if hasattr(tank, "water_depth_m"):
        heights = heights[heights + radius_m < tank.free_surface_z_m - 0.5 * radius_m]
    return heights


#: a ball's radius (m) where the ``[protocol]`` table gives none: a golf ball's (the Ottawa phantoms' object)
DEFAULT_BALL_RADIUS_M = 0.02135


def stated_balls(scene, protocol: dict) -> dict:
    """The ``[protocol]`` table's balls: ``radius_m`` (``ball_radius_m``, else :data:`DEFAULT_BALL_RADIUS_M`),
    ``z_m`` (``ball_z_m``, else the mean height of the ring's electrodes, else the water's mid-depth) and
    ``assumed``: what the table left open and was taken, said in words (empty if nothing).

    >>> from electrosense.meshes import Scene; from electrosense.meshes.cylinder_tank import CylinderTank
    >>> from electrosense.meshes.surface_electrodes import DiscElectrode
    >>> s = Scene(None, tank=CylinderTank(0.15, 0.3), electrodes=[DiscElectrode((0.15, 0.0, -0.02), 0.004)])
    >>> b = stated_balls(s, {"ring": [1], "ball_radius_m": 0.02})
    >>> b["radius_m"], b["z_m"], b["assumed"]
    (0.02, -0.02, ["the balls' height: the ring's plane, z = -0.02 m"])
    """
    assumed = []
    radius = protocol.get("ball_radius_m")
    if radius is None:
        radius = DEFAULT_BALL_RADIUS_M
        assumed.append(f"the balls' radius: {radius} m (a golf ball's)")
    z = protocol.get("ball_z_m")
    if z is None:
        first = scene.n_sensor_electrodes
        ring = [scene.electrodes[int(e) - 1 - first] for e in protocol.get("ring", [])
                if 0 <= int(e) - 1 - first < len(scene.electrodes)]
        if ring:
            z = float(np.mean([e.centre_m[2] for e in ring]))
            assumed.append(f"the balls' height: the ring's plane, z = {z:g} m")
        else:
            z = 0.5 * (scene.tank.floor_z_m + scene.tank.free_surface_z_m) if hasattr(scene.tank, "floor_z_m") else 0.0
            assumed.append(f"the balls' height: the water's mid-depth, z = {z:g} m")
    return {"radius_m": float(radius), "z_m": float(z), "assumed": assumed}


def balls_at(positions_xy, z_m: float, radius_m: float) -> tuple:
    """Spheres of ``radius_m`` at the (x, y) positions (m) of a set-up, centred at height ``z_m``.

    >>> [b.centre_m for b in balls_at([[0.05, 0.0]], 0.01, 0.02)]
    [(0.05, 0.0, 0.01)]
    """
    return tuple(Sphere(centre_m=(float(x), float(y), float(z_m)), radius_m=radius_m) for x, y in positions_xy)


def fit_ball_height(heights, measured, simulated):
    """One height shared by every set-up, from signals simulated at a few heights (quadratic in z).

    ``measured``: {set-up: (R,) measured difference signal}; ``simulated``:
    {set-up: [(R,) signal at each of ``heights``]}. Returns the fitted height
    and, per set-up, the relative RMS misfit at the first (assumed) height and
    at the fitted one, the measured/simulated amplitude and the signal there.

    >>> h = [0.0, 1.0, 2.0]; s = lambda z: np.array([1.0, -1.0]) * (1 + z)
    >>> z, out = fit_ball_height(h, {"A": s(1.5)}, {"A": [s(z) for z in h]})
    >>> round(z, 3), round(out["A"]["at_fitted_height"], 6)
    (1.5, 0.0)
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


@dataclass
class TransferComparison:
    """The comparison of one transfer log with the BEM of its scene (arrays over the reference's transfer rows).

    ``Z_measured_ohm`` and ``Z_model_ohm`` are magnitudes (``sign``: the
    measured sign, which the BEM's agrees with); ``scale`` is the fit on the
    even drives (measured = scale * BEM); ``residual`` the empty tank's
    relative residuals with each half held out in turn; ``offsets`` each
    row's ring offset (None: no ring). ``measured_signals`` /
    ``simulated_signals``: each set-up's difference signal, measured and
    simulated at each of ``heights_m``; ``signals``: measured and simulated
    at the fitted height. ``metrics``: the dict written to metrics.json.
    """

    table: SetupTable
    solution: object
    Z_measured_ohm: np.ndarray
    Z_model_ohm: np.ndarray
    sign: np.ndarray
    drive_pairs: np.ndarray
    drive_index: np.ndarray
    folds: np.ndarray
    scale: float
    residual: np.ndarray
    reciprocity: np.ndarray
    offsets: np.ndarray | None
    metrics: dict
    heights_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    measured_signals: dict = field(default_factory=dict)
    simulated_signals: dict = field(default_factory=dict)
    signals: dict = field(default_factory=dict)

    @property
    def held_out(self) -> np.ndarray:
        """True on the rows of the odd drive patterns (scored, not fitted)."""
        return self.folds == 1


def compare_empty_tank(table: SetupTable, solution, sigma_S_per_m: float, ring=()) -> TransferComparison:
    """The reference set-up against the BEM solution of the empty scene: noise floor, scale fitted on even drives.

    Raises :class:`TransferMismatchError` when a measurement has the opposite
    sign to the BEM's (electrode numbering or sign convention).
    """
    noise = measurement_noise(table.drive, table.measure, table.Z_ohm, ring)
    rec = reciprocity_rel(table.drive, table.measure, table.Z_ohm)
    metrics: dict = {"noise_floor": noise}
    Zm = model_transfer_ohm(solution.conductance.K_S, table.drive, table.measure)
    Zd = table.Z_ohm
    if np.any(np.sign(Zm) != np.sign(Zd)):
        raise TransferMismatchError(f"{np.sum(np.sign(Zm) != np.sign(Zd))} measurements have the opposite sign to "
                                    "the BEM: check the electrode numbering and the log's sign convention")
    Zm, Zd_abs = np.abs(Zm), np.abs(Zd)
    drives, dindex, folds = drive_folds(table.drive)
    held = folds == 1
    base, res0, c0 = score_fit(Zd_abs, [Zm], folds)
    s = float(c0[1][0])
    metrics["empty_heldout_rms_rel"] = base["heldout_rms_rel"]
    metrics["empty_twofold_rms_rel"] = base["twofold_rms_rel"]
    metrics["empty_train_rms_rel"] = _rms(s * Zm[~held] / Zd_abs[~held] - 1)
    metrics["fitted_scale_gain_over_sigma"] = {"scale": s, "sigma_nominal_S_per_m": sigma_S_per_m,
                                               "meaning": "measured V/I = scale * BEM Z at the nominal sigma"}
    off = ring_offsets(table.drive, table.measure, ring)
    if off is not None:
        metrics["empty_rel_error_by_ring_offset"] = mean_by_offset(off, s * Zm / Zd_abs - 1)
    return TransferComparison(table, solution, Zd_abs, Zm, np.sign(Zd), drives, dindex, folds, s, res0, rec, off,
                              metrics)


def compare_objects(comparison: TransferComparison, log, scene, sigma_S_per_m: float, bem_options: dict,
                    protocol: dict) -> dict:
    """Each ball set-up's difference signal, measured against the BEM's; fills ``comparison``'s signals.

    The set-ups are the log's that the ``[protocol]`` table places (a list
    of ball (x, y) per set-up; ``ball_radius_m``, ``ball_z_m``). Returns the
    metrics (``object_rms_rel`` ...) and the seconds of the ball solves.
    """
    t = comparison.table
    ref = str(protocol.get("reference", log.setups[0]))
    stated = stated_balls(scene, protocol)
    radius, zb = stated["radius_m"], stated["z_m"]
    setups = [k for k in log.setups if k != ref and k in protocol]
    heights = ball_heights_m(zb, radius, scene.tank)
    # every ball scene and the empty one on one tank mesh, graded towards every ball: a tank mesh graded to each
    # scene's own balls put the difference of two tank meshes into the signal (a centred ball in a round tank
    # with an even ring: 8.8 % of its signal broke the ring's symmetry, 0.3 % on one mesh)
    focus = objects_focus_m([b for su in setups for z in heights for b in balls_at(protocol[su], z, radius)])
    options = bem_options if focus is None else {**bem_options, "tank_focus_m": focus}
    Z_empty = solved_transfer_ohm(scene, sigma_S_per_m, options, t.drive, t.measure) if setups else None
    dm_all, ds_all, noise = {}, {}, {}
    for setup in setups:
        other = setup_table(log, setup)
        if not (np.array_equal(other.drive, t.drive) and np.array_equal(other.measure, t.measure)):
            raise TransferMismatchError(f"set-up {setup} does not have the reference's measurements")
        dm_all[setup] = other.Z_ohm / t.Z_ohm - 1
        noise[setup] = signal_floor(t.drive, t.measure, t.Z_ohm, other.Z_ohm) / _rms(dm_all[setup])
        ds_all[setup] = [solved_transfer_ohm(replace(scene, objects=balls_at(protocol[setup], z, radius)),
                                             sigma_S_per_m, options, t.drive, t.measure) / Z_empty - 1
                         for z in heights]
    z_fit, ball = fit_ball_height(heights, dm_all, ds_all)
    comparison.heights_m, comparison.measured_signals, comparison.simulated_signals = heights, dm_all, ds_all
    comparison.signals = {k: (dm_all[k], v["signal"]) for k, v in ball.items()}
    symmetric = {}
    for k in setups:       # what no scene with the stated symmetry fits (the scene's and the balls' symmetry)
        maps = scene_symmetries(scene, protocol[k])
        if len(maps) > 1:
            symmetric[k] = {"symmetries": len(maps), "signal_noise_rel": noise[k],
                            "object_rms_rel_floor": symmetric_floor(t.drive, t.measure, dm_all[k], maps)}
    return {"object_rms_rel": {k: v["at_fitted_height"] for k, v in ball.items()},
            "object_symmetric_floor": symmetric,
            "object_rms_rel_at_assumed_height": {k: v["at_assumed_height"] for k, v in ball.items()},
            "ball_height": {"assumed_z_m": zb, "fitted_z_m": z_fit, "scanned_z_m": heights.tolist(),
                            "not_stated": stated["assumed"] if setups else [],    # no ball: nothing was taken
                            "note": "one height shared by every set-up, scanned above the assumed plane "
                                    "(a ball as far below it gives nearly the same signal)",
                            "measured_over_simulated_amplitude": {
                                k: v["measured_over_simulated_amplitude"] for k, v in ball.items()}}}


def compare_transfer_log(log, scene, sigma_S_per_m: float, bem_options: dict, protocol: dict,
                         solution=None) -> TransferComparison:
    """The whole comparison of a transfer log with its scene (one solve of the empty tank, a few per ball set-up).

    ``protocol``: the scene's ``[protocol]`` table (``reference``, ``ring``,
    ball set-ups). ``solution``: the empty scene already solved at ``bem_options`` (else solved here).
    ``metrics`` of the result holds the noise floor, the empty tank's scores, the objects' and the BEM's size and
    times (``bem``).
    """
    table = setup_table(log, str(protocol.get("reference", log.setups[0])))
    t0 = time.perf_counter()
    sol0 = solve_scene(scene, sigma_S_per_m, **bem_options) if solution is None else solution
    bem = {"triangles": sol0.info["triangles"],
           "solve_s": time.perf_counter() - t0 if solution is None else sol0.info["seconds"]}
    comp = compare_empty_tank(table, sol0, sigma_S_per_m, protocol.get("ring", []))
    comp.metrics = {"noise_floor": comp.metrics.pop("noise_floor"), "bem": bem, **comp.metrics}
    maps = scene_symmetries(scene)
    if len(maps) > 1:      # the empty tank: any scene with its symmetry, read through one gain
        log_Z = np.log(np.abs(table.Z_ohm)) - np.mean(np.log(np.abs(table.Z_ohm)))
        comp.metrics["empty_symmetric_floor"] = {
            "symmetries": len(maps), "rms_rel": symmetric_floor(table.drive, table.measure, log_Z, maps) * _rms(log_Z),
            "meaning": "the least RMS misfit of log|Z| (all rows) by any scene with the tank's symmetry read "
                       "through one gain: the spread of log|Z| over each row's images"}
    t0 = time.perf_counter()
    objects = compare_objects(comp, log, scene, sigma_S_per_m, bem_options, protocol)
    bem["ball_solves_s"] = time.perf_counter() - t0
    comp.metrics.update(objects)
    return comp
