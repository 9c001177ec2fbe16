"""The diagnosis of a transfer log's gap to the BEM: candidate effects, each linear about the one solve.

Each candidate is a sum of column blocks beside the BEM's Z (whose
coefficient is the fitted scale), named ``block+block+...``, fitted on the
even drive patterns and scored on the odd ones
(:func:`electrosense.validation.comparison.transfer.score_fit`):

* ``channel_gains`` / ``channel_offsets`` / ``common_offset``: the
  measurement system, per measurement pair; ``pair_parity_gains`` /
  ``pair_parity_offsets``: a gain / a fixed voltage per class of (drive pair,
  measurement pair) by the parity of their places on the ring (a
  multiplexer's two groups);
* ``current_to_electrode_G``: part of the drive current returning through an
  electrode off the ring (a ground);
* ``electrode_angles`` / ``electrode_heights``: each ring electrode moved
  along the ring / up the wall, from the one solve's sensitivities
  (reciprocity, :mod:`electrosense.bem.sensitivity`), with the rigid rotation
  of the ring as gauge;
* ``water_depth``, ``ring_radius``, ``wall_taper``: one more solve each
  (finite differences), and combinations of these; a candidate whose
  changed scene is not valid is skipped with its reason (``skipped``);
* ``common_mode``, ``drive_common_mode``, ``common_mode+channel_gains``: the
  instrument reading a complex fraction of a common-mode voltage
  (:mod:`electrosense.validation.diagnosis.common_mode`; nonlinear, its own
  fit, scored alike);
* each geometric candidate that passes the detection test made exact on the
  BEM at its fitted scene (:func:`solver_at`, the engine's
  :func:`~electrosense.validation.diagnosis.transfer_engine.bem_secants`:
  the electrodes moved or the tank changed, the scene solved again, the
  electrodes' sensitivities taken anew there, every move kept in the water),
  listed beside the linear ones as ``<name>, made exact on the BEM``.

Every candidate is also fitted on the empty tank and scored on the object
set-ups (:func:`heldout_setups`: ``heldout_setups`` of each candidate),
which held-out drives cannot do for what differs between odd and even drives.
The choice (``chosen``, ``verdict``, ``gap_before``, ``gap_after``) is the
pose diagnosis's: the blocks and the common mode as the engine's effects
(:mod:`electrosense.validation.diagnosis.transfer_engine`: whole drive
patterns held out, a BIC charge per parameter, the detection test at a
stated false-alarm rate with the log's reciprocity floor as its noise,
forward selection), each significant geometric block made exact on the BEM
at its fitted scene (:func:`solver_at`); the table of linear candidates
(``candidates``, scored on the odd drives) stays beside it. What it leaves
is split by :func:`~electrosense.validation.diagnosis.transfer_remainder.where_the_rest_lies`
(the tank's symmetric shape, scatter that reciprocal pairs share, the part
that breaks reciprocity). Contact impedances come from the drive pairs' own
voltages (they cannot change a four-electrode transfer impedance).
:func:`one_geometry` asks whether one tank shape explains both the empty
tank and the balls.

Example
-------
Per-channel gains found on synthetic data (two measurement pairs, 1 % and
-1 %):

>>> drive = np.array([[1, 2], [2, 3], [3, 4], [4, 1]] * 2); meas = np.array([[5, 6]] * 4 + [[6, 7]] * 4)
>>> Zm = np.linspace(1.0, 2.0, 8); Zd = Zm * np.r_[[1.01] * 4, [0.99] * 4]
>>> from electrosense.validation.comparison.transfer import drive_folds
>>> cands, _ = score_candidates(channel_blocks(Zm, meas), ["channel_gains"], Zd, drive_folds(drive)[2])
>>> cands["channel_gains"]["gains_rel"], cands["channel_gains"]["heldout_rms_rel"] < 1e-5
([1.01, 0.99], True)
"""
from __future__ import annotations

import time
from dataclasses import replace
from typing import NamedTuple

import numpy as np

from electrosense.bem.protocol import drive_impedances_ohm
from electrosense.bem.sensitivity import shift_sensitivities_ohm_per_m
from electrosense.bem.solve import solve_scene
from electrosense.meshes.cylinder_tank_mesh import disc_problems
from electrosense.meshes.surface_electrodes import DiscElectrode
from electrosense.validation.comparison.transfer import (
    balls_at,
    model_transfer_ohm,
    pair_parity_classes,
    score_fit,
    solved_transfer_ohm,
    stated_balls,
)
from electrosense.validation.diagnosis.common_mode import common_mode_rows, fit_common_mode, instrument_reference
from electrosense.validation.diagnosis.transfer_engine import Block, TransferProblem, diagnose_rows
from electrosense.validation.diagnosis.transfer_remainder import where_the_rest_lies

__all__ = [
    "WallDisc",
    "block_parameters",
    "candidate_blocks",
    "channel_blocks",
    "contact_impedances",
    "diagnose_transfer",
    "engine_blocks",
    "solver_at",
    "moved_electrodes",
    "position_blocks",
    "one_geometry",
    "reshaped_tank",
    "score_candidates",
    "wall_discs",
]


def _on_wall(tank, centre_m) -> bool:
    return hasattr(tank, "on_wall") and tank.on_wall(centre_m)


class WallDisc(NamedTuple):
    """A disc electrode on a cylindrical tank's wall: its index in the scene, centre (m), unit vectors, radius (m).

    ``azimuthal`` moves it along the ring (counter-clockwise seen from
    above), ``upward`` up the wall's generator (it follows a taper).
    """

    index: int
    centre_m: np.ndarray
    normal_out: np.ndarray
    azimuthal: np.ndarray
    upward: np.ndarray
    radius_m: float


def wall_discs(scene) -> list[WallDisc]:
    """The :class:`WallDisc` of every disc electrode on a cylindrical tank's wall (none on a box tank).

    >>> from electrosense.meshes import Scene; from electrosense.meshes.cylinder_tank import CylinderTank
    >>> s = Scene(None, tank=CylinderTank(0.1, 0.1), electrodes=[DiscElectrode((0.0, 0.1, 0.0), 0.005)])
    >>> w = wall_discs(s)[0]
    >>> w.index, w.normal_out.round(6).tolist(), w.azimuthal.round(6).tolist(), w.upward.round(6).tolist()
    (0, [0.0, 1.0, -0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0])
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
        upward = np.array([slope * np.cos(phi), slope * np.sin(phi), 1.0]) / np.hypot(1.0, slope)
        out.append(WallDisc(i, np.array(e.centre_m), normal, np.array([-np.sin(phi), np.cos(phi), 0.0]), upward,
                            e.radius_m))
    return out


def reshaped_tank(scene, radius_m=None, floor_radius_m=None):
    """The scene with its cylindrical tank's top/floor radii changed; wall discs follow the wall (same angle, height).

    >>> from electrosense.meshes import Scene; from electrosense.meshes.cylinder_tank import CylinderTank
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


def channel_blocks(Z_model, measure) -> dict:
    """The measurement system's column blocks: per-pair gains (they replace the scale), per-pair offsets, one offset.

    >>> b = channel_blocks(np.array([1.0, 2.0, 3.0]), np.array([[1, 2], [2, 3], [1, 2]]))
    >>> {k: len(v) for k, v in b.items()}
    {'channel_gains': 2, 'channel_offsets': 2, 'common_offset': 1}
    """
    mpairs, mindex = np.unique(measure, axis=0, return_inverse=True)
    chan = [(mindex.ravel() == j).astype(float) for j in range(len(mpairs))]
    return {"channel_gains": [Z_model * c for c in chan], "channel_offsets": chan,
            "common_offset": [np.ones(len(Z_model))]}


def candidate_blocks(name: str) -> list[str]:
    """The column blocks of a candidate named ``a+b+...``: the scale (BEM's Z) first, unless gains replace it.

    >>> candidate_blocks("water_depth+electrode_angles"), candidate_blocks("channel_gains"), candidate_blocks("scale")
    (['scale', 'water_depth', 'electrode_angles'], ['channel_gains'], ['scale'])
    """
    names = name.split("+")
    return names if names[0] in ("scale", "channel_gains") else ["scale"] + names


def pair_parity_blocks(Z_model, drive, measure, ring) -> dict:
    """``pair_parity_gains``: a gain for each class of (drive pair, measurement pair) by the parity of their place
    along the ring, beside the common scale (the even-even class is its reference): a multiplexer that routes odd
    and even pairs through different groups. ``pair_parity_offsets``: a fixed voltage per unit current added in
    each class (all four): that multiplexer's crosstalk from the drive into the measurement, which matters most,
    relative to the reading, on the far side where the transfer impedance is smallest, and alternates there with
    the ring offset's parity. Empty without a ring.

    Drives held out by parity never see the odd drives' classes; set-ups held out do (:func:`heldout_setups`).

    >>> b = pair_parity_blocks(np.ones(4), np.array([[1, 2], [2, 3], [1, 2], [2, 3]]),
    ...                        np.array([[3, 4], [4, 1], [4, 1], [3, 4]]), [1, 2, 3, 4])
    >>> [c.tolist() for c in b["pair_parity_gains"]]
    [[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0], [0.0, 1.0, 0.0, 0.0]]
    >>> np.sum(b["pair_parity_offsets"], axis=0).tolist()          # every row in one class
    [1.0, 1.0, 1.0, 1.0]
    """
    cls = pair_parity_classes(drive, measure, ring)
    if cls is None:
        return {}
    return {"pair_parity_gains": [Z_model * (cls == k) for k in (1, 2, 3)],
            "pair_parity_offsets": [(cls == k).astype(float) for k in range(4)]}


def heldout_setups(comparison, blocks: dict, candidates, R_ring_m=None, common_mode=None) -> dict:
    """Each candidate fitted on the empty tank (all its drives) and scored on the object set-ups, and the reverse.

    What a candidate fits (a channel's gain, an electrode's place, the tank's
    shape) stays when an object goes in, so the empty tank's fit must predict
    the object set-ups' measured magnitudes: each of their rows is the
    candidate's model times the BEM's object-over-empty ratio (objects at the
    stated height). ``common_mode``: the designs of
    :func:`common_mode_candidates`, to score those too. Returns
    ``{name: {"empty_to_objects_rms_rel", "objects_to_empty_rms_rel", set-up: rms, "fitted_on_the_empty_tank":
    parameters}}`` (empty without object set-ups).
    """
    setups = list(comparison.measured_signals)
    if not setups:
        return {}
    ratio = [1 + comparison.simulated_signals[k][0] for k in setups]
    Zd0 = comparison.Z_measured_ohm
    R = len(Zd0)

    def stack(col):
        return np.concatenate([col] + [col * r for r in ratio])

    Zd = np.concatenate([Zd0] + [Zd0 * (1 + comparison.measured_signals[k]) for k in setups])
    folds = np.repeat([0, 1], [R, R * len(setups)])
    stacked = {k: [stack(c) for c in cols] for k, cols in blocks.items()}
    fitted, resid = score_candidates(stacked, ["scale", *candidates], Zd, folds, R_ring_m)   # params: empty tank's fit
    for name, (Z, X, ch) in (common_mode or {}).items():
        ch = None if ch is None else np.tile(ch, 1 + len(setups))
        resid[name] = fit_common_mode(Zd, stack(Z), stack(X), folds, ch)[1]

    def rms(r):
        return float(np.sqrt(np.mean(r ** 2)))

    scores = ("heldout_rms_rel", "twofold_rms_rel", "n_parameters")
    return {name: {"empty_to_objects_rms_rel": rms(r[R:]), "objects_to_empty_rms_rel": rms(r[:R]),
                   **{k: rms(r[R * (i + 1):R * (i + 2)]) for i, k in enumerate(setups)},
                   "fitted_on_the_empty_tank": {k: v for k, v in fitted.get(name, {}).items() if k not in scores}}
            for name, r in resid.items()}


def block_parameters(block: str, c, scale: float, R_ring_m: float | None = None) -> dict:
    """The physical parameters of one fitted block (coefficients ``c``; ``scale``: the fitted scale).

    >>> block_parameters("water_depth", np.array([-0.01]), 2.0)
    {'depth_change_m': -0.005}
    >>> block_parameters("ring_radius", np.array([0.02]), 2.0, R_ring_m=0.15)
    {'ring_radius_change_m': 0.01, 'ring_radius_m': 0.16}
    >>> block_parameters("electrode_heights", np.array([0.002, -0.004]), 2.0)
    {'height_offsets_mm': [1.0, -2.0]}
    """
    c = np.asarray(c, float)
    if block == "water_depth":
        return {"depth_change_m": float(c[0] / scale)}
    if block == "ring_radius":
        return {"ring_radius_change_m": float(c[0] / scale), "ring_radius_m": R_ring_m + float(c[0] / scale)}
    if block == "wall_taper":
        return {"floor_radius_change_m": float(c[0] / scale)}
    if block == "electrode_angles":
        return {"arc_offsets_mm": np.round(1e3 * c / scale, 2).tolist()}
    if block == "electrode_heights":
        return {"height_offsets_mm": np.round(1e3 * c / scale, 2).tolist()}
    if block.startswith("current_to_electrode"):
        return {"fraction": float(c[0] / scale)}
    if block == "pair_parity_gains":
        return {"pair_parity_gains_rel": dict(zip(("even-odd", "odd-even", "odd-odd"),
                                                  np.round(1 + c / scale, 4).tolist()))}
    if block == "pair_parity_offsets":
        return {"pair_parity_offsets_ohm": dict(zip(("even-even", "even-odd", "odd-even", "odd-odd"),
                                                    (c / scale).tolist()))}
    if block == "channel_gains":
        return {"gains_rel": np.round(c / np.mean(c), 4).tolist()}
    return {}


def score_candidates(blocks: dict, candidates, Z_measured, folds, R_ring_m=None) -> tuple[dict, dict]:
    """Fit and score every candidate (a name ``a+b+...`` of ``blocks``); returns {name: scores and parameters}
    and {name: 2-fold residuals}.

    ``blocks``: {name: list of (R,) columns}, with ``"scale"`` the BEM's Z.
    The ``electrode_angles`` block gets the rigid rotation of the ring (the
    sum of the arc offsets) as gauge: it changes nothing. The
    ``electrode_heights`` block keeps the ring's mean height: moving the whole
    ring up is nearly a change of scale (left to ``water_depth``). Parameters are
    those of the fit that holds the odd drives out.
    """
    cands, resid = {}, {}
    for name in candidates:
        names = candidate_blocks(name)
        cols = [c for b in names for c in blocks[b]]
        start = np.cumsum([0] + [len(blocks[b]) for b in names])
        gauged = [names.index(b) for b in ("electrode_angles", "electrode_heights") if b in names]
        g = np.zeros((len(gauged), len(cols))) if gauged else None
        for row, k in enumerate(gauged):
            g[row, start[k]:start[k + 1]] = 1.0
        sc, res, coefs = score_fit(Z_measured, cols, folds, g)
        c, se = coefs[1], coefs["se"][1]
        scale = c[0] if names[0] == "scale" else 1.0
        for k, b in enumerate(names):
            block = block_parameters(b, c[start[k]:start[k + 1]], scale, R_ring_m)
            sc.update(block)
            sc.update(_standard_errors(block, block_parameters(b, c[start[k]:start[k + 1]] + se[start[k]:start[k + 1]],
                                                               scale, R_ring_m)))
        cands[name] = sc
        resid[name] = res
    return cands, resid


def _standard_errors(params: dict, shifted: dict) -> dict:
    """``{name}_se`` of each numeric parameter: its change when every coefficient moves by one standard error
    (first order; the coefficients' correlations left out). The noise's share only: a fit linear about one
    solve is also biased by its linearisation, which the refinement on the BEM removes (on a synthetic
    phantom, electrode heights off by up to 3 mm against 0.7 mm standard errors before, within 2 of them after).

    >>> _standard_errors({"depth_change_m": -0.005, "note": "x"}, {"depth_change_m": -0.004})
    {'depth_change_m_se': 0.001}
    """
    out = {}
    for k, v in params.items():
        if isinstance(v, dict):
            out[f"{k}_se"] = {kk: round(abs(shifted[k][kk] - vv), 6) for kk, vv in v.items()}
        elif isinstance(v, list):
            out[f"{k}_se"] = np.round(np.abs(np.subtract(shifted[k], v)), 6).tolist()
        elif isinstance(v, float):
            out[f"{k}_se"] = round(abs(shifted[k] - v), 9)
    return out


def position_blocks(solution, wall, comparison) -> dict:
    """The ``electrode_angles`` and ``electrode_heights`` blocks: d|Z|/ds (ohm/m) of each row for each wall disc
    moved along the ring / up the wall, from one solve's fields (reciprocity; both directions sampled at once).

    ``wall``: the :class:`WallDisc` of the moving electrodes; ``comparison``
    gives the rows (drive pairs and index, measurement pairs, signs).
    """
    t = comparison.table
    mpairs, mindex = np.unique(t.measure, axis=0, return_inverse=True)
    Jall = shift_sensitivities_ohm_per_m(
        solution, comparison.drive_pairs, mpairs, np.array([w.index + 1 for w in wall] * 2),
        [w.centre_m for w in wall] * 2, [w.normal_out for w in wall] * 2,
        [w.azimuthal for w in wall] + [w.upward for w in wall], [w.radius_m for w in wall] * 2)
    J = comparison.sign[:, None] * Jall[comparison.drive_index, mindex.ravel()]     # (R, 2E)
    return {"electrode_angles": list(J[:, :len(wall)].T), "electrode_heights": list(J[:, len(wall):].T)}


def moved_electrodes(scene, wall, arc_m=None, up_m=None):
    """The scene with each wall disc ``wall[k]`` moved by ``arc_m[k]`` along the ring and ``up_m[k]`` up the wall.

    >>> from electrosense.meshes import Scene; from electrosense.meshes.cylinder_tank import CylinderTank
    >>> s = Scene(None, tank=CylinderTank(0.1, 0.1), electrodes=[DiscElectrode((0.1, 0.0, 0.0), 0.005)])
    >>> c = moved_electrodes(s, wall_discs(s), [0.1 * np.pi / 2], [0.01]).electrodes[0].centre_m
    >>> np.round(c, 6).tolist()
    [0.0, 0.1, 0.01]
    """
    tank = scene.tank
    es = list(scene.electrodes)
    for k, w in enumerate(wall):
        c = np.asarray(w.centre_m, float) + (0.0 if up_m is None else up_m[k]) * w.upward
        r = float(tank.radius_at(c[2]))
        phi = np.arctan2(c[1], c[0]) + (0.0 if arc_m is None else arc_m[k]) / r
        es[w.index] = replace(es[w.index], centre_m=(r * np.cos(phi), r * np.sin(phi), float(c[2])))
    return replace(scene, electrodes=tuple(es))


def step_on_the_wall(scene, wall, arc_m, up_m, d_arc_m, d_up_m, halvings: int = 6) -> tuple[float, str]:
    """The largest fraction (1, 1/2, ... 1/2**halvings, else 0) of a move that keeps every wall disc placeable.

    ``arc_m``, ``up_m``: where the discs ``wall`` are now (offsets from the
    scene's positions, m); ``d_arc_m``, ``d_up_m``: the move. Placeable is
    :func:`electrosense.meshes.cylinder_tank_mesh.disc_problems`' test, with the discs' order around the
    ring kept (none passes a neighbour or goes half way round). Returns the fraction and, when
    it is below 1, what the full move would have done.

    >>> from electrosense.meshes import Scene; from electrosense.meshes.cylinder_tank import CylinderTank
    >>> s = Scene(None, tank=CylinderTank(0.1, 0.2), electrodes=[DiscElectrode((0.1, 0.0, 0.0), 0.005)])
    >>> w = wall_discs(s)
    >>> step_on_the_wall(s, w, [0.0], [0.0], [0.0], [0.05])
    (1.0, '')
    >>> f, why = step_on_the_wall(s, w, [0.0], [0.0], [0.0], [1.3]); f, why[:37]
    (0.0625, 'would make: electrode 1 at (0.1, 0.0,')
    """
    tank = scene.tank
    arc_m, up_m, d_arc_m, d_up_m = (np.asarray(v, float) for v in (arc_m, up_m, d_arc_m, d_up_m))
    why = ""
    for k in range(halvings + 1):
        f = 0.5 ** k
        moved = moved_electrodes(scene, wall, arc_m + f * d_arc_m, up_m + f * d_up_m).electrodes
        problems = disc_problems(tank, moved) + _order_problems(scene.electrodes, moved, wall, arc_m + f * d_arc_m)
        if not problems:
            return f, why
        why = why or "would make: " + "; ".join(problems[:2])
    return 0.0, why


def common_mode_candidates(K_S, drive, measure, Z_measured, folds, ring, floating=()) -> tuple[dict, dict, dict]:
    """The measurement system's common-mode error (:mod:`electrosense.validation.diagnosis.common_mode`) as candidates.

    ``common_mode``: each measurement pair's common-mode voltage against the
    instrument's ground (a ground electrode in the water, else the ring's
    mean), read with a complex fraction ``c``; ``drive_common_mode``: the
    drive pair's half voltage (a current source referenced at one terminal);
    ``common_mode+channel_gains``: the first with a gain per channel. Scored
    as the linear candidates (fold 1 held out), with standard errors.
    Returns the candidates, their residuals and each one's design
    ``{name: (Z, X, channel)}`` (the arguments of
    :func:`~electrosense.validation.diagnosis.common_mode.fit_common_mode`).
    """
    ref = instrument_reference(np.shape(K_S)[0], ring, floating) if ring else list(range(1, np.shape(K_S)[0] + 1))
    Z, Vcm, half_drive = common_mode_rows(K_S, drive, measure, ref)
    channel = np.unique(measure, axis=0, return_inverse=True)[1].ravel()
    designs = {"common_mode": (Z, Vcm, None), "drive_common_mode": (Z, half_drive, None),
               "common_mode+channel_gains": (Z, Vcm, channel)}
    cands, resid = {}, {}
    for name, (Zs, X, ch) in designs.items():
        sc, res, params = fit_common_mode(Z_measured, Zs, X, folds, ch)
        cands[name] = {**sc, **params, "reference_electrodes": ref if name != "drive_common_mode" else "drive pair"}
        resid[name] = res
    return cands, resid, designs


def _order_problems(electrodes, moved, wall, arc_m) -> list[str]:
    """The wall discs' order around the ring must survive a move: every angular gap between neighbours stays open.

    >>> from electrosense.meshes import Scene; from electrosense.meshes.cylinder_tank import CylinderTank
    >>> s = Scene(None, tank=CylinderTank(0.1, 0.2), electrodes=[DiscElectrode((0.1, 0.0, 0.0), 0.005),
    ...                                                          DiscElectrode((0.0, 0.1, 0.0), 0.005)])
    >>> w, arc = wall_discs(s), np.array([0.2, 0.0])                   # the first goes past the second
    >>> _order_problems(s.electrodes, moved_electrodes(s, w, arc).electrodes, w, arc)
    ['electrodes 1 and 2 would pass each other along the ring']
    """
    phi = np.mod([np.arctan2(*np.asarray(electrodes[w.index].centre_m)[1::-1]) for w in wall], 2 * np.pi)
    turn = np.asarray(arc_m, float) / np.array([np.hypot(*np.asarray(moved[w.index].centre_m)[:2]) for w in wall])
    order = np.argsort(phi)
    gaps = np.diff(np.r_[phi[order], phi[order][0] + 2 * np.pi])
    moved_gaps = gaps + np.diff(np.r_[turn[order], turn[order][0]])
    return [f"electrodes {wall[order[k]].index + 1} and {wall[order[(k + 1) % len(order)]].index + 1} would pass "
            "each other along the ring" for k in np.flatnonzero(moved_gaps <= 0)[:1]]


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


def engine_blocks(blocks: dict, Z_model, measure, tank, R_ring_m: float | None, wall, ring) -> list[Block]:
    """The column blocks of :func:`diagnose_transfer` as the engine's :class:`~.transfer_engine.Block`: each
    parameter in physical units with the largest plausible magnitude as its bound.

    Bounds: a gain's relative change 0.5; an offset the largest model magnitude; a ground's share of the current
    1; the depth 0.4 of itself; the ring's and the floor's radius 0.3 of the ring's; an electrode's move half the
    electrodes' spacing along the ring. The channels' mean gain (the scale's), the ring's rigid rotation and its
    mean height are gauges (the last parameter is minus the sum of the others).

    >>> Zm = np.array([1.0, 2.0, 3.0]); meas = np.array([[1, 2], [2, 3], [1, 2]])
    >>> [(b.name, b.param_names, b.gauge) for b in engine_blocks(channel_blocks(Zm, meas), Zm, meas, None, None, [], [])]
    ... # doctest: +NORMALIZE_WHITESPACE
    [('channel_gains', ('gain_rel_change_m1-2', 'gain_rel_change_m2-3'), True),
     ('channel_offsets', ('offset_m1-2_ohm', 'offset_m2-3_ohm'), False), ('common_offset', ('offset_ohm',), False)]
    """
    pairs = [f"m{p}-{q}" for p, q in np.unique(measure, axis=0).tolist()]
    offset = float(np.max(np.abs(Z_model)))
    spacing = np.pi * R_ring_m / max(len(ring), 1) if R_ring_m else 0.01
    discs = [f"e{w.index + 1}" for w in wall]
    spec = {
        "channel_gains": ([f"gain_rel_change_{p}" for p in pairs], "1", 0.5, True,
                          "each measurement channel reads (1 + g) times its voltage"),
        "channel_offsets": ([f"offset_{p}_ohm" for p in pairs], "ohm", offset, False,
                            "each measurement channel adds a fixed voltage per unit current"),
        "common_offset": (["offset_ohm"], "ohm", offset, False, "every channel adds one fixed voltage"),
        "pair_parity_gains": (["gain_even-odd", "gain_odd-even", "gain_odd-odd"], "1", 0.5, False,
                              "a gain per class of (drive pair, measurement pair) by their places' parity"),
        "pair_parity_offsets": (["offset_even-even_ohm", "offset_even-odd_ohm", "offset_odd-even_ohm",
                                 "offset_odd-odd_ohm"], "ohm", offset, False,
                                "a fixed voltage per unit current per class of (drive pair, measurement pair) by "
                                "their places' parity"),
        "electrode_angles": ([f"arc_{d}_m" for d in discs], "m", spacing, True,
                             "each ring electrode moved along the ring (the ring's rigid rotation as gauge)"),
        "electrode_heights": ([f"up_{d}_m" for d in discs], "m", spacing, True,
                              "each ring electrode moved up the wall (the ring's mean height as gauge)"),
        "water_depth": (["depth_change_m"], "m", 0.4 * getattr(tank, "water_depth_m", 0.0), False,
                        "the water deeper by d than stated"),
        "ring_radius": (["ring_radius_change_m"], "m", 0.3 * (R_ring_m or 0.0), False,
                        "the tank wider by dR at the ring (both radii scaled)"),
        "wall_taper": (["floor_radius_change_m"], "m", 0.3 * (R_ring_m or 0.0), False,
                       "the tank's floor radius larger by dF (the wall's taper)"),
    }
    out = []
    for name, cols in blocks.items():
        if name == "scale":
            continue
        names, unit, bound, gauge, describe = spec.get(name, (["fraction"], "1", 1.0, False,
                                                              "a share of the drive current returns through "
                                                              f"electrode {name.rsplit('_', 1)[-1]}"))
        out.append(Block(name, np.stack(cols, axis=1), tuple(names), unit, bound, gauge, describe))
    return out


def bem_stepped_row(step: dict, R_ring_m: float | None = None) -> dict:
    """A row of the candidates' table for a block made exact on the BEM (an item of the engine's ``bem_secants``):
    its held-out gap (the engine's folds: every row held out once, so also its ``twofold_rms_rel``), its
    parameters as :func:`block_parameters` states them (electrode moves in mm; ``R_ring_m`` for the ring's
    radius) with their standard errors.

    >>> row = bem_stepped_row({"effect": "electrode_heights", "heldout_rms_rel": 0.01, "solves": [{}, {}],
    ...                        "parameters": {"up_e1_m": 0.002, "up_e2_m": -0.002},
    ...                        "standard_errors": {"up_e1_m": 1e-4, "up_e2_m": 1e-4}})
    >>> row["height_offsets_mm"], row["height_offsets_mm_se"], row["n_parameters"], row["steps"]
    ([2.0, -2.0], [0.1, 0.1], 1, 2)
    """
    name = step["effect"]
    values, errors = np.array(list(step["parameters"].values())), np.array(list(step["standard_errors"].values()))
    params = block_parameters(name, values, 1.0, R_ring_m)
    row = {"heldout_rms_rel": step["heldout_rms_rel"], "twofold_rms_rel": step["heldout_rms_rel"],
           "n_parameters": max(len(values) - (name in ("electrode_angles", "electrode_heights")), 1),
           "heldout_by": "whole drive patterns, every fifth in a fold (the engine's folds)",
           "steps": len(step["solves"]), **params,
           **_standard_errors(params, block_parameters(name, values + errors, 1.0, R_ring_m))}
    notes = [s["note"] for s in step["solves"] if s.get("note")] + [s["refused"] for s in step["solves"]
                                                                     if s.get("refused")]
    return {**row, "notes": notes} if notes else row


#: the blocks whose fitted scene the BEM can solve (:func:`solver_at`)
GEOMETRIC_BLOCKS = ("electrode_angles", "electrode_heights", "water_depth", "ring_radius", "wall_taper")


def solver_at(scene, wall, R_ring_m, sigma_S_per_m: float, bem_options: dict, comparison):
    """``solve_at(name, theta) -> (|Z| (R,), fraction, note, columns)``: the BEM of ``scene`` with a geometric block's
    physical parameters ``theta`` applied (:data:`GEOMETRIC_BLOCKS`); an electrode move that would leave the wall
    or cross a neighbour shortened (:func:`step_on_the_wall`) and said, one that cannot be placed at all refused;
    an electrode block's columns at the moved scene (:func:`position_blocks`), else None."""
    tank = scene.tank
    drive, measure = comparison.table.drive, comparison.table.measure

    def changed(name, theta):
        if name in ("electrode_angles", "electrode_heights"):
            zero = np.zeros(len(wall))
            d_arc, d_up = (theta, zero) if name == "electrode_angles" else (zero, theta)
            fraction, why = step_on_the_wall(scene, wall, zero, zero, d_arc, d_up)
            if fraction == 0:
                raise ValueError(f"no fraction of the fitted move can be placed: it {why}")
            note = f"shortened to {fraction:g} of the fitted move, which {why}" if fraction < 1 else ""
            return moved_electrodes(scene, wall, fraction * d_arc, fraction * d_up), fraction, note
        if name == "water_depth":
            return replace(scene, tank=replace(tank, water_depth_m=tank.water_depth_m + float(theta[0]))), 1.0, ""
        if name == "ring_radius":
            f = 1 + float(theta[0]) / R_ring_m
            return reshaped_tank(scene, f * tank.radius_m, f * tank.floor_radius_m), 1.0, ""
        if name == "wall_taper":
            return reshaped_tank(scene, floor_radius_m=tank.floor_radius_m + float(theta[0])), 1.0, ""
        raise ValueError(f"{name} is not a geometric block")

    def solve_at(name, theta):
        moved, fraction, note = changed(name, np.asarray(theta, float))
        sol = solve_scene(moved, sigma_S_per_m, **bem_options)
        Z = np.abs(model_transfer_ohm(sol.conductance.K_S, drive, measure))
        columns = None
        if name in ("electrode_angles", "electrode_heights"):   # the BEM's sensitivities where it now is
            here = [w for w in wall_discs(moved) if w.index in {v.index for v in wall}]
            columns = np.stack(position_blocks(sol, here, comparison)[name], axis=1)
        return Z, fraction, note, columns

    return solve_at


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
    blocks = {"scale": [Zm], **channel_blocks(Zm, meas)}
    candidates = ["channel_gains", "channel_offsets", "common_offset"]
    # ground electrode(s) off the ring carrying part of the drive current (sink shared with it)
    for g in [e for e in range(1, K0.shape[0] + 1) if e not in ring and e not in floating]:
        alt = np.abs(model_transfer_ohm(K0, np.c_[drive[:, 0], np.full(len(drive), g)], meas))
        blocks[f"current_to_electrode_{g}"] = [alt - Zm]
        candidates.append(f"current_to_electrode_{g}")
    # electrode positions on the wall, along the ring and up the wall: sensitivities from the one solve
    # (reciprocity), both directions sampled at once
    t0 = time.perf_counter()
    wall = [w for w in wall_discs(scene) if w.index + 1 in ring]      # the measured electrodes
    if wall:
        blocks.update(position_blocks(sol0, wall, comparison))
        candidates += ["electrode_angles", "electrode_heights", "electrode_angles+electrode_heights"]
    seconds["position_sensitivity_s"] = time.perf_counter() - t0

    def derivative(changed_scene, step):
        return (Zm - solved_transfer_ohm(changed_scene, sigma_S_per_m, bem_options, drive, meas)) / step

    skipped = {}       # candidates whose changed scene cannot be built or solved: why

    def changed(name, make):
        """``make()``, or None with the reason kept in ``skipped`` when the changed scene is not a valid one."""
        try:
            return make()
        except (ValueError, MemoryError) as exc:
            skipped[name] = str(exc)
            return None

    # water depth: one more solve (finite difference of a sixth of the depth)
    tank = scene.tank
    if hasattr(tank, "water_depth_m"):
        dH = tank.water_depth_m / 6
        t0 = time.perf_counter()
        col = changed("water_depth", lambda: derivative(
            replace(scene, tank=replace(tank, water_depth_m=tank.water_depth_m - dH)), dH))
        if col is not None:
            blocks["water_depth"] = [col]
            candidates.append("water_depth")
        seconds["depth_solve_s"] = time.perf_counter() - t0
    # the tank's shape at the ring: radius (both radii scaled) and taper (floor radius alone), one solve each;
    # columns per metre of the RING's radius (taper: per metre of the floor's radius)
    shape, R_ring = None, None
    if hasattr(tank, "radius_at") and ring:
        R_ring = float(tank.radius_at(float(np.mean([scene.electrodes[e - 1].centre_m[2] for e in ring]))))
        t0 = time.perf_counter()
        f = 0.9
        scaled = reshaped_tank(scene, f * tank.radius_m, f * tank.floor_radius_m)
        Z_scaled = changed("ring_radius", lambda: solved_transfer_ohm(scaled, sigma_S_per_m, bem_options, drive, meas))
        dF = 0.1 * tank.floor_radius_m
        taper = changed("wall_taper", lambda: derivative(
            reshaped_tank(scene, floor_radius_m=tank.floor_radius_m - dF), dF))
        seconds["shape_solves_s"] = time.perf_counter() - t0
        if Z_scaled is not None:
            blocks["ring_radius"] = [(Zm - Z_scaled) / ((1 - f) * R_ring)]
            shape = {"scene": scaled, "R_ring_m": R_ring, "R_ring_scaled_m": f * R_ring, "Z": Z_scaled}
            candidates.append("ring_radius")
            if "water_depth" in blocks:
                candidates.append("ring_radius+water_depth")
        if taper is not None:
            blocks["wall_taper"] = [taper]
            candidates.append("wall_taper")
            if Z_scaled is not None:
                candidates.append("ring_radius+wall_taper")
    if wall and "water_depth" in blocks:
        candidates += ["water_depth+electrode_angles", "water_depth+electrode_angles+electrode_heights",
                       "water_depth+electrode_angles+channel_offsets"]
    blocks.update(pair_parity_blocks(Zm, drive, meas, ring))
    if "pair_parity_gains" in blocks:
        candidates += ["pair_parity_gains", "pair_parity_offsets"]
    cands, resid = score_candidates(blocks, candidates, Zd, folds, R_ring)
    cm_cands, cm_resid, cm_designs = common_mode_candidates(K0, drive, meas, Zd, folds, ring, floating)
    cands.update(cm_cands)
    resid.update(cm_resid)
    across = heldout_setups(comparison, blocks, candidates, R_ring, cm_designs)
    for name, scores in across.items():
        if name in cands:
            cands[name]["heldout_setups"] = scores
    resid = {"stated geometry": comparison.residual, **resid}
    # the noise the engine assumes: the reciprocity floor, less an instrument's part that breaks reciprocity
    floor = comparison.metrics["noise_floor"]["fit_noise_rel"]
    # the choice: the pose diagnosis's engine on these rows (:mod:`.transfer_engine`)
    t0 = time.perf_counter()
    Z_signed, V_cm, _ = cm_designs["common_mode"]
    problem = TransferProblem.scaled(comparison.drive_index, Zm, Zd, np.sign(Z_signed),
                                     engine_blocks(blocks, Zm, meas, tank, R_ring, wall, ring), V_cm)
    engine, *heldout = diagnose_rows(problem, floor, solve_at=solver_at(scene, wall, R_ring, sigma_S_per_m,
                                                                      bem_options, comparison),
                                  solvable=GEOMETRIC_BLOCKS,
                                  noise_source=comparison.metrics["noise_floor"]["fit_noise_from"])
    seconds["engine_s"] = time.perf_counter() - t0
    # the engine's (measured - predicted) / model, turned to the table's sign (model / measured - 1 to first order;
    # its RMS is then the engine's gaps)
    before, after = (-r for r in heldout)
    for step in engine["bem_secants"]:      # the BEM's answer beside the linear candidates
        if step["heldout_rms_rel"] < step["heldout_rms_rel_linear"]:
            cands[f"{step['effect']}, made exact on the BEM"] = bem_stepped_row(step, R_ring)
    chosen = engine["chosen"] or "unexplained"
    held = comparison.held_out
    r0 = comparison.residual[held]
    worst = np.argsort(-np.abs(r0))[:4]
    diagnosis = {
        "chosen": chosen, "verdict": engine["verdict"], "gap_before": engine["gap_before"],
        "gap_after": engine["gap_after"], "shrink": engine["shrink"],
        "noise_rel": floor, "noise_from": comparison.metrics["noise_floor"]["fit_noise_from"],
        "rule": ("the pose diagnosis's engine (:mod:`transfer_engine`): each candidate fitted on four fifths of the "
                 "drive patterns and scored on the rest, a BIC charge per parameter, an effect named only when the "
                 f"best held-out improvement passes the detection test at a {engine['detection']['alpha']:.0%} "
                 "false-alarm rate under the log's reciprocity floor as white noise; combinations by forward "
                 "selection"),
        "engine": engine,
        "smallest_heldout_candidate": min(cands, key=lambda k: cands[k]["heldout_rms_rel"]),
        "candidates": cands,
        "stated_geometry_heldout_setups": across.get("scale"),
        "skipped": skipped,
        "contact_impedances": contact_impedances(K0, t.drive_pairs, t.drive_Z_ohm, scene.electrodes),
        "largest_heldout_errors": [{"drive": drive[held][i].tolist(), "measure": meas[held][i].tolist(),
                                    "rel": float(r0[i])} for i in worst],
        "gap_before_split": where_the_rest_lies(drive, meas, comparison.offsets, before, ring=ring),
        "remaining": where_the_rest_lies(drive, meas, comparison.offsets, after, ring=ring)}
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
    stated = stated_balls(shape["scene"], protocol)
    radius, zb = stated["radius_m"], stated["z_m"]
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
