"""The KTC2023 tanks: the scene's unknowns fitted on one folder, every tank of other folders predicted from its truth.

:func:`fit_ktc` fits, on a folder of the series (``ref.mat``, ``dataN.mat``,
``trueN.mat``: :func:`~electrosense.validation.bench.transfer.ktc_mat.read_ktc_folder`):

1. the empty tank (:mod:`~electrosense.validation.comparison.ktc_fit`): the
   scale (current's unit over conductivity), the electrodes' arc, the water
   depth, the electrodes' height and position, each electrode's contact
   impedance, and the instrument's offset per channel; scored on held-out
   patterns (the unknowns refitted on the even patterns predict the odd ones
   and the other way round: ``ref_rms_rel``);
2. the tanks with objects (their change, data minus reference): what only
   objects can tell (the electrode ring's rotation from the sources' angles,
   the truth frame's shift, the metal's contact impedance) and each tank's
   drift (a nuisance: the water's conductivity changed between the two
   files); scored held out by tank (the fit without that tank, linearised
   about the full fit, predicts it, its drift from :func:`water_change`).

:func:`predict_folder` then predicts every tank of another folder from its
truth and that folder's reference, with no further fitting of the scene: the
change ``s Mpat^T (Z_objects - Z_empty) Inj`` against the measured change,
with one number taken from the file, the water's change since the reference
(:func:`water_change`: cross-fitted by pattern, each fold scored with the
scale of the other). The figure without it is kept beside
(``difference_rms_rel_reference_water``).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from electrosense.validation.bench.transfer.ktc_mat import KtcFolder, linear_floor, usable
from electrosense.validation.comparison.ktc_fit import OBJECT_ONLY, Block, KtcProblem, fit_blocks, ktc_unknowns
from electrosense.validation.comparison.ktc_model import KtcForward, truth_objects, volts

__all__ = ["KtcFit", "fit_ktc", "predict_folder", "rms_rel", "file_floors", "pattern_folds", "water_change"]


def rms_rel(err, ref) -> float:
    """RMS of ``err`` over RMS of ``ref`` (finite entries of both)."""
    ok = np.isfinite(err) & np.isfinite(ref)
    den = float(np.sqrt(np.mean(np.asarray(ref)[ok] ** 2))) if ok.any() else 0.0
    return float(np.sqrt(np.mean(np.asarray(err)[ok] ** 2)) / den) if den > 0 else float("nan")


def pattern_folds(n_patterns: int) -> np.ndarray:
    """Fold of each pattern: 0 even (0-based), 1 odd: each fold holds every kind of pattern."""
    return np.arange(n_patterns) % 2


def water_change(residual, total, folds) -> dict:
    """The water's change since the reference, one relative scale per file, each fold's from the other folds.

    A file measured after the reference, with the same currents, sees every voltage scaled by ``1 + k`` when the
    water's conductivity (its temperature) or the current source moved in between: a state of that file that no
    truth mask carries. ``k`` is the least-squares scale of ``total`` (the file's voltages the scale multiplies)
    that best cancels ``residual`` (predicted minus measured change); each fold (of patterns) is corrected with the
    ``k`` fitted on the other folds, so the corrected residual is scored on patterns its ``k`` did not see.

    Parameters
    ----------
    residual, total : (P, M) arrays, volts, NaN where not scored.
    folds : (P,) int, the fold of each pattern (:func:`pattern_folds`).

    Returns
    -------
    dict with ``residual`` (the corrected residual, NaN where not scored), ``k`` (fitted on all folds), ``k_se``
    (its standard error under independent errors of the corrected residual's RMS: a lower bound where the errors
    are correlated), ``k_fold_spread`` (half the range of the folds' ``k``: what the patterns themselves say of
    it), ``k_by_fold`` and ``in_sample`` (True where a fold had to use its own ``k``: no other fold had data).

    Examples
    --------
    >>> import numpy as np
    >>> V = np.arange(1.0, 13.0).reshape(4, 3)
    >>> out = water_change(-0.05 * V, V, pattern_folds(4))
    >>> round(out["k"], 6), float(np.nanmax(np.abs(out["residual"]))) < 1e-12
    (0.05, True)
    """
    r = np.asarray(residual, float)
    v = np.asarray(total, float)
    ok = np.isfinite(r) & np.isfinite(v)
    folds = np.broadcast_to(np.asarray(folds)[:, None], r.shape)

    def scale(on):
        vv = float(np.sum(v[on] ** 2))
        return -float(np.sum(v[on] * r[on])) / vv if vv > 0 else 0.0

    out = np.full(r.shape, np.nan)
    by_fold, in_sample = {}, False
    for f in np.unique(folds[ok]):
        others = ok & (folds != f)
        in_sample |= not others.any()
        k_f = scale(others) if others.any() else scale(ok)
        on = ok & (folds == f)
        out[on] = r[on] + k_f * v[on]
        by_fold[int(f)] = k_f
    k = scale(ok)
    rest = r[ok] + k * v[ok]
    vv = float(np.sum(v[ok] ** 2))
    se = float(np.sqrt(np.mean(rest ** 2) / vv)) if vv > 0 and rest.size else float("nan")
    fold_k = [scale(ok & (folds == f)) for f in by_fold]
    spread = 0.5 * (max(fold_k) - min(fold_k)) if len(fold_k) > 1 else float("nan")
    return {"residual": out, "k": k, "k_se": se, "k_fold_spread": spread, "k_by_fold": by_fold,
            "in_sample": bool(in_sample)}


def file_floors(folder: KtcFolder) -> dict:
    """The linear floor of every file's voltages (``ref``) and of each tank's change (data minus reference)."""
    ok_r, _, _ = usable(folder.ref)
    out = {"ref.mat": linear_floor(folder.ref.injection, np.where(ok_r, folder.ref.voltages_V, np.nan))}
    for name, (d, _) in folder.tanks.items():
        ok, _, _ = usable(d)
        out[f"{name}.mat"] = linear_floor(d.injection, np.where(ok, d.voltages_V, np.nan))
        diff = np.where(ok & ok_r, d.voltages_V - folder.ref.voltages_V, np.nan)
        out[f"{name}.mat (change)"] = linear_floor(d.injection, diff)
    return out


@dataclass
class KtcFit:
    """What the fit found: the unknowns' vector ``x`` and names, the forward model, the stage fits, scores."""

    x: np.ndarray
    names: list
    forward: KtcForward
    ref_fit: object
    object_fit: object | None
    problem: KtcProblem
    n_electrodes: int
    n_channels: int
    scores: dict = field(default_factory=dict)
    heldout: dict = field(default_factory=dict)
    seconds: dict = field(default_factory=dict)

    @property
    def values(self) -> dict:
        return {n: float(v) for n, v in zip(self.names, self.x)}

    def geometry(self):
        return self.problem.geometry(self.x)

    def zeta(self):
        return self.problem.zeta(self.x)

    @property
    def scale(self) -> float:
        return float(np.exp(self.x[self.names.index("log_scale")]))

    def offsets(self):
        return self.problem.offsets(self.x)


def _ref_block(folder: KtcFolder, mask=None) -> Block:
    ok, _, _ = usable(folder.ref)
    if mask is not None:
        ok = ok & mask
    fl = linear_floor(folder.ref.injection, np.where(ok, folder.ref.voltages_V, np.nan))
    return Block("ref", "total", folder.ref.voltages_V, ok, 1.0 / max(fl["noise_rms"], 1e-12), folder.ref.injection,
                 folder.ref.measurement_pattern)


def _difference_blocks(folder: KtcFolder, prefix: str = "") -> list[Block]:
    ok_r, _, _ = usable(folder.ref)
    out = []
    for name, (d, _) in folder.tanks.items():
        ok, _, _ = usable(d)
        ok &= ok_r
        if not ok.any():
            continue
        dm = np.where(ok, d.voltages_V - folder.ref.voltages_V, 0.0)
        fl = linear_floor(d.injection, np.where(ok, dm, np.nan))
        out.append(Block(prefix + name, "difference", dm, ok, 1.0 / max(fl["noise_rms"], 1e-12), d.injection,
                         d.measurement_pattern))
    return out


def fit_ktc(folder: KtcFolder, n_modes: int = 30, progress=print, max_nfev: int = 20) -> KtcFit:
    """Fit the scene's unknowns on a folder (see the module docstring)."""
    E, M = folder.ref.measurement_pattern.shape
    objects = {name: truth_objects(t) for name, (_, t) in folder.tanks.items()}
    forward = KtcForward(objects, n_modes=n_modes)
    t0 = time.perf_counter()
    progress(f"fitting the empty tank ({E} electrodes, {folder.ref.injection.shape[1]} patterns)")
    rblock = _ref_block(folder)
    fixed1 = set(OBJECT_ONLY)
    ref_fit, _ = fit_blocks(forward, [rblock], E, M, fixed=fixed1, max_nfev=max_nfev)
    t1 = time.perf_counter()
    # held-out patterns: refit on one fold, predict the other
    folds = pattern_folds(folder.ref.injection.shape[1])
    pred = np.full(folder.ref.voltages_V.shape, np.nan)
    for f in (0, 1):
        progress(f"empty tank: refit without the {'even' if f == 0 else 'odd'} patterns")
        train = np.broadcast_to((folds != f)[:, None], pred.shape)
        fit_f, prob_f = fit_blocks(forward, [_ref_block(folder, train)], E, M, start=ref_fit.values, fixed=fixed1,
                                   max_nfev=max(4, max_nfev // 3))
        full = Block("ref", "total", folder.ref.voltages_V, np.ones(pred.shape, bool), 1.0, folder.ref.injection,
                     folder.ref.measurement_pattern)
        p = KtcProblem(forward, [full], E, M).predictions(fit_f.x)[0]
        pred[folds == f] = p[folds == f]
    ok_r, _, _ = usable(folder.ref)
    held = np.where(ok_r, pred - folder.ref.voltages_V, np.nan)
    t2 = time.perf_counter()
    blocks = _difference_blocks(folder)
    object_fit = None
    x = ref_fit.x
    names = ref_fit.names
    problem = KtcProblem(forward, [rblock], E, M)
    heldout = {"ref_patterns_residual": held, "ref_patterns_prediction": pred}
    if blocks:
        progress(f"fitting the tanks with objects ({', '.join(b.tank for b in blocks)})")
        free = set(OBJECT_ONLY) | {f"drift_{b.tank}" for b in blocks}
        all_names = [u.name for u in ktc_unknowns(E, M, tanks=[b.tank for b in blocks])]
        start = dict(ref_fit.values)
        object_fit, problem = fit_blocks(forward, blocks, E, M, start=start,
                                         fixed=[n for n in all_names if n not in free],
                                         max_nfev=max(6, max_nfev // 2))
        x, names = object_fit.x, object_fit.names
        heldout["tanks"] = _leave_one_tank_out(object_fit, problem, blocks)
    t3 = time.perf_counter()
    fit = KtcFit(np.asarray(x), list(names), forward, ref_fit, object_fit, problem, E, M, heldout=heldout,
                 seconds={"empty_tank_s": t1 - t0, "heldout_patterns_s": t2 - t1, "objects_s": t3 - t2})
    fit.scores["ref_rms_rel"] = rms_rel(held, np.where(ok_r, folder.ref.voltages_V, np.nan))
    fit.scores["ref_train_rms_rel"] = rms_rel(ref_fit.residual / rblock.weight, folder.ref.voltages_V[rblock.mask])
    return fit


def _leave_one_tank_out(fit, problem: KtcProblem, blocks: list[Block]) -> dict:
    """Each tank predicted by the fit on the others (one Gauss-Newton step from the full fit).

    The tank's drift is first set to 0 (``reference_water``), then taken from :func:`water_change` on the
    prediction (``water``: cross-fitted by pattern), as :func:`predict_folder` does for another folder's tanks.
    Returns {tank: {"reference_water": residual (P, M) in volts, NaN where not scored, "water": the same corrected}}.
    """
    J, r = fit.jacobian, fit.residual
    free = [i for i, n in enumerate(fit.names) if n not in _fixed_names(problem)]
    steps = np.array([u.step for u in problem.unknowns])
    rows, start = {}, 0
    for b in blocks:
        n = int(b.mask.sum())
        rows[b.tank] = slice(start, start + n)
        start += n
    out = {}
    for b in blocks:
        others = np.ones(len(r), bool)
        others[rows[b.tank]] = False
        cols = [j for j in range(len(free)) if fit.names[free[j]] != f"drift_{b.tank}"]
        A = J[others][:, cols] * steps[np.array(free)[cols]][None]
        d = -np.linalg.lstsq(A, r[others], rcond=1e-6)[0] * steps[np.array(free)[cols]]
        dx = np.zeros(len(free))
        dx[cols] = d
        jd = free.index(fit.names.index(f"drift_{b.tank}"))
        dx[jd] = -fit.x[free[jd]]
        res_t = r[rows[b.tank]] + J[rows[b.tank]] @ dx
        R = np.full(b.mask.shape, np.nan)
        R[b.mask] = res_t / b.weight
        V = np.full(b.mask.shape, np.nan)             # the prediction's total voltages, which the drift scales
        V[b.mask] = J[rows[b.tank], jd] / b.weight
        out[b.tank] = {"reference_water": R, "water": water_change(R, V, pattern_folds(b.mask.shape[0]))["residual"]}
    return out


def _fixed_names(problem: KtcProblem) -> set:
    return problem.fixed


def predict_folder(fit: KtcFit, folder: KtcFolder, label: str, progress=print) -> dict:
    """Every tank of ``folder`` predicted from its truth and the folder's reference (no further fitting).

    Returns {tank: {"predicted": (P, M), "measured": (P, M), "mask", "total_predicted", "objects", metrics}}.
    """
    E, M = folder.ref.measurement_pattern.shape
    if E != fit.n_electrodes:
        raise ValueError(f"{folder.path}: {E} electrodes, the fit's tanks have {fit.n_electrodes}")
    offsets = fit.offsets() if M == fit.n_channels else np.zeros(M)      # the instrument's, where channels match
    geom = fit.geometry()
    zeta = fit.zeta()
    s = fit.scale
    fw = fit.forward
    ok_r, out_r, _ = usable(folder.ref)
    Z0 = fw.impedance("ref", geom, zeta)
    out = {}
    for name, (d, truth) in folder.tanks.items():
        progress(f"predicting {label}/{name}")
        key = f"{label}/{name}"
        fw.objects[key] = truth_objects(truth)
        try:
            Z = fw.impedance(key, geom, zeta)
        except ValueError as exc:
            out[name] = {"error": str(exc)}
            continue
        ok, out_e, left = usable(d)
        ok &= ok_r
        dm = np.where(ok, d.voltages_V - folder.ref.voltages_V, np.nan)
        dp = s * volts(Z - Z0, d.injection, d.measurement_pattern)
        tot = s * volts(Z, d.injection, d.measurement_pattern) + offsets[None]
        dpm = np.where(ok, dp, np.nan)
        fl = linear_floor(d.injection, dm)
        meas_tot = np.where(ok, d.voltages_V, np.nan)
        # the water's change since the reference: one scale for the file, each fold of patterns corrected by the
        # scale fitted on the other fold (the only thing taken from the file; nothing about its objects)
        # what the scale multiplies: the medium's voltages, not the instrument's offsets
        medium = folder.ref.voltages_V - offsets[None] + dp
        folds = pattern_folds(d.injection.shape[1])
        water = water_change(dpm - dm, np.where(ok, medium, np.nan), folds)
        k_f = np.array([water["k_by_fold"].get(int(f), water["k"]) for f in folds])[:, None]
        tot_water = tot + k_f * (tot - offsets[None])
        out[name] = {"predicted": dm + water["residual"],
                     "predicted_reference_water": dpm, "measured": dm, "mask": ok, "total_predicted": tot_water,
                     "objects": fw.objects[key], "truth": truth,
                     "metrics": {"difference_rms_rel": rms_rel(water["residual"], dm),
                                 "difference_rms_rel_reference_water": rms_rel(dpm - dm, dm),
                                 "water_change_rel": water["k"], "water_change_rel_se": water["k_se"],
                                 "water_change_rel_fold_spread": water["k_fold_spread"],
                                 "water_change_in_sample": water["in_sample"],
                                 "difference_floor_rel": fl["floor_rms_rel"],
                                 "total_rms_rel": rms_rel(np.where(ok, tot_water, np.nan) - meas_tot, meas_tot),
                                 "total_rms_rel_reference_water": rms_rel(np.where(ok, tot, np.nan) - meas_tot,
                                                                          meas_tot),
                                 "amplitude_measured_over_predicted": float(np.nansum(dpm * dm) / np.nansum(dpm ** 2)),
                                 "electrodes_out_of_use": out_e, "patterns_left_out": left,
                                 "scored_voltages": int(ok.sum())}}
        del fw.objects[key]
    return out
