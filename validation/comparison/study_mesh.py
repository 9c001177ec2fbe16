"""The BEM mesh a real-tank study solves on where the scene file does not say: the coarsest whose error the noise hides.

A scene file's ``[bem]`` table (the tank's far edge, the electrodes' rim edge
over their radius, the edge's growth away from a rim) is the user's word and
is used as written. Without it, the mesher's defaults are meant for a single
accurate solve (12 400 triangles on a 30 cm pail with 16 tacks, 15-30 s a
solve), while a study solves the tank some fifty times. So the study climbs a
ladder of meshes from coarse to fine (:func:`mesh_level`: every length
``REFINE`` times the level's before, the last level the solver's defaults) and
takes the first whose own error on the reference set-up's ``log |Z|`` is at
most ``BEM_ERROR_OVER_NOISE`` times the data's noise per measurement (its
reciprocity floor, less an instrument's part that breaks reciprocity:
:func:`~electrosense.validation.comparison.transfer.measurement_noise`): there
the BEM adds at most 12 % to the noise the fits assume.

The error of a level is estimated against the next finer one
(:func:`richardson_error`): the difference of the two meshes' ``log |Z|``
(their mean removed: a scale, which the instrument's scale takes) over
``1 - REFINE ** p``. With two meshes ``p`` is the conservative order 1 (the
current density at an electrode's edge is singular); once three are solved,
the order the two differences show (:func:`observed_order`), kept within
``[BEM_ORDER, MAX_ORDER]``. On the pail with 16 tacks the differences between
levels 0-1, 1-2 and 2-3 were 0.14 / 0.11 / 0.04 % (observed orders 1.35 and
4.2): order 1 estimates levels 0 / 1 / 2 at 0.71 / 0.52 / 0.21 %, the order 1.35
of levels 0-2 levels 0 / 1 at 0.54 / 0.40 %, against 0.23 / 0.14 / 0.05 % from a
mesh two levels finer than the defaults: both on the safe side.

Example
-------
One row of two moving by 0.75 % between meshes of ratio 0.8 is, the mean removed, 0.37 % a row, and at order 1 an
error of 1.9 % RMS:

>>> z_coarse, z_fine = np.log([1.0, 2.0]), np.log([1.0, 2.0 * 1.0075])
>>> round(richardson_error(z_coarse, z_fine), 5)
0.01868
"""

from __future__ import annotations

import time

import numpy as np

from electrosense.bem.solve import solve_scene
from electrosense.meshes.cylinder_tank_mesh import default_far_edge_length_m
from electrosense.meshes.surface_electrodes import DEFAULT_EDGE_FRACTION, DEFAULT_ELECTRODE_GRADING

__all__ = ["BEM_ORDER", "MAX_ORDER", "REFINE", "LEVELS", "BEM_ERROR_OVER_NOISE", "mesh_level", "refined_options",
           "richardson_error", "observed_order", "study_bem_options"]

#: the BEM's order of convergence assumed for a mesh's error (Richardson): the conservative one, since the
#: current density at an electrode's edge is singular (the finer levels converge faster)
BEM_ORDER = 1.0
#: the largest order a ladder's observed one is taken as (P0 collocation on graded meshes)
MAX_ORDER = 2.0
#: every mesh length of a level over the one before it
REFINE = 0.8
#: levels of the ladder: level LEVELS - 1 is the solver's defaults, level 0 the coarsest (1 / REFINE ** 3 = 1.95x)
LEVELS = 4
#: a mesh is taken where its estimated error is at most this fraction of the data's per-measurement noise
BEM_ERROR_OVER_NOISE = 0.5


def refined_options(bem_options: dict, tank, factor: float) -> dict:
    """``bem_options`` with every mesh length times ``factor``: the tank's far edge (default from ``tank``), the
    electrodes' rim edge over their radius and the edge's growth per metre away from a rim (defaults filled in).

    >>> from electrosense.meshes.cylinder_tank import CylinderTank
    >>> refined_options({"edge_fraction": 0.5}, CylinderTank(0.15, 0.3, 0.26), 0.8)
    {'edge_fraction': 0.4, 'electrode_grading': 0.4, 'tank_edge_length_m': 0.02}
    """
    defaults = {"edge_fraction": DEFAULT_EDGE_FRACTION, "electrode_grading": DEFAULT_ELECTRODE_GRADING,
                "tank_edge_length_m": None if tank is None else default_far_edge_length_m(tank)}
    out = dict(bem_options)
    for key, default in defaults.items():
        value = bem_options.get(key, default)
        if value is not None:
            out[key] = round(float(factor) * float(value), 12)
    return out


def mesh_level(tank, level: int) -> dict:
    """The BEM options of ``level`` of the study's ladder (0 coarsest, ``LEVELS - 1`` the solver's defaults).

    >>> from electrosense.meshes.cylinder_tank import CylinderTank
    >>> {k: round(v, 4) for k, v in mesh_level(CylinderTank(0.15, 0.3, 0.26), 0).items()}
    {'edge_fraction': 0.4883, 'electrode_grading': 0.9766, 'tank_edge_length_m': 0.0488}
    """
    if not 0 <= level < LEVELS:
        raise ValueError(f"mesh level {level} is not among 0..{LEVELS - 1}")
    return refined_options({}, tank, REFINE ** (level - (LEVELS - 1)))


def richardson_error(log_Z_coarse, log_Z_fine, order: float = BEM_ORDER, refine: float = REFINE) -> float:
    """RMS error of the coarse mesh's ``log |Z|`` (their mean removed) estimated from a mesh ``refine`` finer."""
    d = np.asarray(log_Z_coarse, float) - np.asarray(log_Z_fine, float)
    d = (d - d.mean()) / (1.0 - refine ** order)
    return float(np.sqrt(np.mean(d ** 2)))


def observed_order(log_Z_coarse, log_Z_middle, log_Z_fine, refine: float = REFINE) -> float:
    """The order of convergence three meshes (each ``refine`` times the one before) show, within
    ``[BEM_ORDER, MAX_ORDER]``: ``log(|d_1| / |d_2|) / log(1 / refine)`` of their successive differences' RMS
    (means removed).

    >>> z = np.log([1.0, 2.0])
    >>> round(observed_order(z, z + [0, 0.01], z + [0, 0.01 + 0.01 * 0.8 ** 1.5]), 6)
    1.5
    """
    def rms(a, b):
        d = np.asarray(a, float) - np.asarray(b, float)
        return float(np.sqrt(np.mean((d - d.mean()) ** 2)))

    d1, d2 = rms(log_Z_coarse, log_Z_middle), rms(log_Z_middle, log_Z_fine)
    if not (d1 > 0 and d2 > 0):
        return BEM_ORDER
    return float(np.clip(np.log(d1 / d2) / np.log(1.0 / refine), BEM_ORDER, MAX_ORDER))


def study_bem_options(scene, sigma_S_per_m: float, stated: dict, transfer_ohm, noise_rel: float,
                      log=print) -> tuple[dict, dict, object]:
    """The BEM options a study solves ``scene`` with, and what decided them.

    Parameters
    ----------
    scene : Scene
        The empty tank as the scene file states it.
    stated : dict
        The scene file's ``[bem]`` table (empty where it has none): used as written when not empty.
    transfer_ohm : callable
        ``K_S -> Z`` (ohm) of the reference set-up's rows.
    noise_rel : float
        The data's per-measurement noise (relative); not finite or not positive: the solver's defaults.

    Returns
    -------
    options : dict
    record : dict
        ``chosen`` ("stated", a level, or "defaults"), ``levels`` (each level's options, triangles, seconds and
        estimated error), ``threshold_rel`` and ``meaning``: for the study's metrics.
    solution : the BEM solution of ``scene`` at ``options`` where the ladder solved it (the study need not solve it
        again), else None.
    """
    if stated:
        return dict(stated), {"chosen": "stated", "options": dict(stated),
                              "meaning": "the scene file's [bem] table, used as written"}, None
    record: dict = {"noise_rel": noise_rel, "threshold_rel": BEM_ERROR_OVER_NOISE * noise_rel, "levels": [],
                    "meaning": f"no [bem] table in the scene file: the coarsest mesh whose error on the reference's "
                               f"log|Z| (against a mesh {REFINE} times finer, order {BEM_ORDER} or the order three meshes show up to "
                               f"{MAX_ORDER}, mean removed) is at "
                               f"most {BEM_ERROR_OVER_NOISE} times the noise per measurement the fits assume"}
    last = mesh_level(scene.tank, LEVELS - 1)
    if not (np.isfinite(noise_rel) and noise_rel > 0):
        return last, {**record, "chosen": "defaults", "options": last,
                      "meaning": "no [bem] table and no reciprocity floor to judge a mesh by: the solver's defaults"}, None
    solved: list = []          # log|Z| of each level solved, and its solution
    solutions: list = []

    def level_log_Z(k):
        while len(solved) <= k:
            options = mesh_level(scene.tank, len(solved))
            t0 = time.perf_counter()
            sol = None
            try:
                sol = solve_scene(scene, sigma_S_per_m, **options)
                z = np.log(np.abs(transfer_ohm(sol.conductance.K_S)))
                entry = {"level": len(solved), "options": options, "triangles": sol.info["triangles"]}
            except ValueError as exc:    # a mesh too coarse for the scene: the next level
                z, entry = None, {"level": len(solved), "options": options, "error": str(exc)}
            entry["solve_s"] = time.perf_counter() - t0
            solved.append(z)
            solutions.append(sol)
            record["levels"].append(entry)
        return solved[k]

    for k in range(LEVELS - 1):
        if level_log_Z(k) is None or level_log_Z(k + 1) is None:
            continue
        # level k - 1 again, at the order levels k - 1, k, k + 1 show; then level k at that order (order 1 at k = 0)
        order = BEM_ORDER
        if k >= 1 and level_log_Z(k - 1) is not None:
            order = observed_order(level_log_Z(k - 1), level_log_Z(k), level_log_Z(k + 1))
        for j in ([k - 1, k] if order != BEM_ORDER else [k]):
            err = richardson_error(level_log_Z(j), level_log_Z(j + 1), order)
            record["levels"][j].update(error_rms_rel=err, order=order)
            log(f"study mesh level {j}: {record['levels'][j]['triangles']} triangles, its error {100 * err:.2f} % "
                f"at order {order:.2f} (threshold {100 * record['threshold_rel']:.2f} %)")
            if err <= record["threshold_rel"]:
                options = mesh_level(scene.tank, j)
                return options, {**record, "chosen": j, "options": options}, solutions[j]
    return last, {**record, "chosen": "defaults", "options": last}, solutions[-1] if len(solutions) == LEVELS else None
