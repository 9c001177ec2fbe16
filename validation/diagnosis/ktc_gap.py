"""Where the KTC model's gap lies, and which effect explains how much of it, held out by pattern and by tank.

Where: the residuals (measured minus model, each voltage held out) by
measurement channel, by electrode (the channels that read it), and by
pattern family (adjacent drives; all against one electrode), on the empty
tank and on the tanks' changes.

What explains it: candidate effects, each linear about the fitted scene
(columns beside the model, least squares), fitted on part of the data and
scored on the rest:

* on the empty tank, held out by pattern (even patterns fitted, odd ones
  scored and the other way round): ``none`` (the scene with its scale only),
  ``channel_offsets`` (the instrument adds a fixed voltage to each channel),
  ``channel_gains``, ``offsets+gains``, ``common_mode+offsets`` (each channel
  also reads a fraction of its pair's common-mode voltage against the
  electrodes' mean), ``electrode_angles+offsets`` (each electrode moved along
  the wall: the model's finite differences, a geometry error), ``2-D
  electrodes+offsets`` (the electrodes spanning the water: the 2-D
  assumption, scale refitted);
* on the tanks' changes, held out by tank (fitted on the other tanks):
  ``none``, ``channel_gains``, ``2-D electrodes``; and the water's change since the
  reference (one scale per tank, cross-fitted by pattern:
  :func:`~electrosense.validation.comparison.ktc.water_change`).

The shrink of a candidate is ``1 - heldout / heldout(none)``.
"""
from __future__ import annotations

import numpy as np

from electrosense.validation.bench.transfer.ktc_mat import linear_floor, usable
from electrosense.validation.comparison.ktc import pattern_folds, rms_rel, water_change
from electrosense.validation.comparison.ktc_model import volts
from electrosense.validation.diagnosis.transfer_engine import Block, TransferProblem, diagnose_rows

__all__ = ["diagnose_ktc", "empty_tank_problem", "pattern_families", "by_electrode", "heldout_linear"]


def pattern_families(injection) -> list[str]:
    """A family name per pattern: ``adjacent`` (its two current electrodes are neighbours among those that ever
    carry current), ``against eK`` (K the one of its two that more patterns share), else ``other``.

    >>> inj = np.zeros((8, 4)); inj[[0, 2], 0] = 1, -1; inj[[2, 4], 1] = 1, -1; inj[[0, 4], 2] = -1, 1
    >>> inj[[0, 6], 3] = -1, 1
    >>> pattern_families(inj)                  # e7 and e1 are neighbours round the ring of e1, e3, e5, e7
    ['adjacent', 'adjacent', 'against e1', 'adjacent']
    """
    inj = np.asarray(injection, float)
    carry = np.flatnonzero(np.abs(inj).max(axis=1) > 0)
    place = {int(e): i for i, e in enumerate(carry)}
    uses = (np.abs(inj) > 0).sum(axis=1)
    out = []
    for p in range(inj.shape[1]):
        on = np.flatnonzero(np.abs(inj[:, p]) > 0)
        if len(on) != 2:
            out.append("other")
            continue
        a, b = (place[int(e)] for e in on)
        if abs(a - b) == 1 or abs(a - b) == len(carry) - 1:
            out.append("adjacent")
        else:
            e = on[np.argmax(uses[on])]
            out.append(f"against e{int(e) + 1}")
    return out


def by_electrode(residual, measurement_pattern) -> np.ndarray:
    """RMS (E,) of the residuals (P, M) over the channels that read each electrode (NaN ignored)."""
    R = np.asarray(residual, float)
    fin = np.isfinite(R)
    ms = np.where(fin.any(axis=0), np.nansum(R ** 2, axis=0) / np.maximum(fin.sum(axis=0), 1), np.nan)   # (M,)
    W = (np.abs(np.asarray(measurement_pattern)) > 0) & np.isfinite(ms)[None]                          # (E, M)
    return np.sqrt(np.array([ms[w].mean() if w.any() else np.nan for w in W]))


def _where(residual, reference, mp, families) -> dict:
    R = np.asarray(residual, float)
    ref = np.asarray(reference, float)
    fam = {}
    for f in sorted(set(families)):
        rows = np.array([g == f for g in families])
        fam[f] = rms_rel(R[rows], ref[rows])
    den = float(np.sqrt(np.nanmean(ref ** 2)))
    fin = np.isfinite(R)
    by_channel = np.where(fin.any(axis=0), np.nansum(R ** 2, axis=0) / np.maximum(fin.sum(axis=0), 1), np.nan)
    return {"by_channel_rel": (np.sqrt(by_channel) / den).tolist(),
            "by_electrode_rel": (by_electrode(R, mp) / den).tolist(),
            "by_family_rel": fam}


def heldout_linear(measured, columns, mask, folds) -> np.ndarray:
    """Least squares ``measured ~ columns @ c`` fitted on each fold's complement, predicted on the fold.

    ``measured`` (N,), ``columns`` (N, K), ``mask`` (N,) usable, ``folds`` (N,) ints. Returns the held-out
    residuals (measured - prediction), NaN where not usable.

    >>> x = np.linspace(0, 1, 10); y = 3 * x
    >>> r = heldout_linear(y, x[:, None], np.ones(10, bool), np.arange(10) % 2)
    >>> bool(np.abs(r).max() < 1e-12)
    True
    """
    out = np.full(len(measured), np.nan)
    for f in np.unique(folds):
        tr = mask & (folds != f)
        te = mask & (folds == f)
        if not te.any():
            continue
        A = columns[tr]
        keep = np.abs(A).sum(axis=0) > 0
        c = np.zeros(columns.shape[1])
        if keep.any():
            c[keep] = np.linalg.lstsq(A[:, keep], measured[tr], rcond=1e-10)[0]
        out[te] = measured[te] - columns[te] @ c
    return out


def _channel_columns(values, n_channels) -> np.ndarray:
    """(P*M, M): ``values`` placed on each channel's own column (gains), or ones (offsets) when values is None."""
    P = values.shape[0]
    X = np.zeros((P * n_channels, n_channels))
    idx = np.arange(P * n_channels)
    X[idx, np.tile(np.arange(n_channels), P)] = values.ravel()
    return X


def empty_tank_problem(U, ok, V, cm, D, V2, n_electrodes: int) -> TransferProblem:
    """The empty tank's voltages as the diagnosis engine's problem (:class:`~.transfer_engine.TransferProblem`):
    the usable voltages signed, each relative to the model's RMS, a pattern's voltages a pass.

    ``U`` (P, M) measured (V), ``ok`` (P, M) usable, ``V`` the scene's voltages at scale 1, ``cm`` each channel's
    common-mode voltage, ``D`` (P M, E) their change per degree of each electrode along the wall, ``V2`` the scene
    with electrodes spanning the water. The candidates: an offset per channel (V), a gain per channel (their mean
    the scale's), one fraction of the common-mode voltage, each electrode along the wall (deg; the ring's
    rotation as gauge), and the way towards 2-D electrodes (1: all of it). A channel with no usable voltage
    has no parameter.

    A channel reading 0.1 V too much, at 1 mV of noise, named by the engine:

    >>> P, M = 20, 4; rng = np.random.default_rng(0); V = rng.normal(size=(P, M)); ok = np.ones((P, M), bool)
    >>> cm, D, V2 = 0.3 * rng.normal(size=(P, M)), rng.normal(size=(P * M, 3)), V + rng.normal(size=(P, M))
    >>> U = 2 * V + np.r_[0.1, 0, 0, 0][None] + 1e-3 * rng.normal(size=(P, M))
    >>> problem = empty_tank_problem(U, ok, V, cm, D, V2, 3)
    >>> round(problem.scale, 2), sorted(problem.blocks)
    (2.0, ['channel_gains', 'channel_offsets', 'common_mode', 'electrode_angles', 'two_d_electrodes'])
    >>> out, _, _ = diagnose_rows(problem, noise=1e-3 / float(np.sqrt(np.mean(U**2))))
    >>> out["chosen"], round(out["parameters"]["channel_offsets"]["offset_m1_V"], 3)
    ('channel_offsets', 0.1)
    """
    P, M = U.shape
    rows = ok.ravel()
    channels = np.flatnonzero(ok.any(axis=0))
    off = _channel_columns(np.ones((P, M)), M)[rows][:, channels]
    gains = _channel_columns(V, M)[rows][:, channels]
    s = float(np.sum(U[ok] * V[ok]) / np.sum(V[ok] ** 2))       # the offsets' columns in measured volts
    bound = float(np.max(np.abs(U[ok])))
    names = [f"m{c + 1}" for c in channels]
    blocks = [
        Block("channel_offsets", off / s, tuple(f"offset_{c}_V" for c in names), "V", bound,
              describe="each channel adds a fixed voltage"),
        Block("channel_gains", gains, tuple(f"gain_rel_change_{c}" for c in names), "1", 0.5, gauge=True,
              describe="each channel reads (1 + g) times its voltage (their mean is the scale's)"),
        Block("common_mode", cm.ravel()[rows, None], ("fraction",), "1", 1.0,
              describe="each channel also reads a fraction of its pair's common-mode voltage"),
        Block("electrode_angles", D[rows], tuple(f"angle_e{k + 1}_deg" for k in range(n_electrodes)), "deg",
              180.0 / n_electrodes, gauge=True,
              describe="each electrode moved along the wall (the ring's rigid rotation as gauge)"),
        Block("two_d_electrodes", (V2 - V).ravel()[rows, None], ("fraction_towards_2d",), "1", 2.0,
              describe="the electrodes reaching towards spanning the water (1: the 2-D model)"),
    ]
    index = np.repeat(np.arange(P), M)[rows]
    norm = float(np.sqrt(np.mean(V[ok] ** 2)))
    return TransferProblem.scaled(index, V.ravel()[rows], U.ravel()[rows], blocks=blocks, norm=norm)


def diagnose_ktc(fit, folder, predictions: dict, progress=print) -> dict:
    """The diagnosis (see the module docstring): ``{"metrics": ..., "arrays": ...}``."""
    ref = folder.ref
    inj, mp, U = ref.injection, ref.measurement_pattern, ref.voltages_V
    P, M = U.shape
    families = pattern_families(inj)
    ok, _, _ = usable(ref)
    geom, zeta, s = fit.geometry(), fit.zeta(), fit.scale
    fw = fit.forward
    Z = fw.impedance("ref", geom, zeta)
    V = volts(Z, inj, mp)                                          # the scene at scale 1
    folds = np.repeat(pattern_folds(P), M)
    y = np.where(ok, U, 0.0).ravel()
    mask = ok.ravel()
    cols = {"none": [V.ravel()[:, None]]}
    off = _channel_columns(np.ones((P, M)), M)
    gains = _channel_columns(V, M)
    cols["channel_offsets"] = [V.ravel()[:, None], off]
    cols["channel_gains"] = [gains]
    cols["offsets+gains"] = [gains, off]
    # common mode: each channel reads c (V_p + V_q)/2 against the electrodes' mean potential
    pot = np.einsum("ef,fp->pe", Z, inj)
    pot = pot - pot.mean(axis=1, keepdims=True)
    cm = 0.5 * np.einsum("pe,em->pm", pot, np.abs(mp))
    cols["common_mode+offsets"] = [V.ravel()[:, None], cm.ravel()[:, None], off]
    # electrode angles: each electrode moved along the wall (finite differences of the model)
    progress("diagnosis: each electrode moved along the wall (finite differences)")
    h = 0.05
    dang = []
    for k in range(fit.n_electrodes):
        offs = np.zeros(fit.n_electrodes)
        offs[k] = h
        g2 = type(geom)(**{**geom.__dict__, "angle_offsets_deg": tuple(offs)})
        dang.append(((volts(fw.impedance("ref", g2, zeta), inj, mp) - V) / h).ravel())
    D = np.stack(dang, axis=1)
    cols["electrode_angles+offsets"] = [V.ravel()[:, None], D, off]
    # the 2-D assumption: electrodes spanning the water
    g2d = type(geom)(**{**geom.__dict__, "height_frac": 1.0, "position": 0.0})
    V2 = volts(fw.impedance("ref", g2d, zeta), inj, mp)
    cols["2-D electrodes+offsets"] = [V2.ravel()[:, None], off]
    ref_scores, ref_resid = {}, {}
    for name, blocks in cols.items():
        X = np.hstack(blocks)
        r = heldout_linear(y, X, mask, folds).reshape(P, M)
        ref_resid[name] = r
        ref_scores[name] = rms_rel(r, np.where(ok, U, np.nan))
    base = ref_scores["none"]
    ref_table = {k: {"heldout_rms_rel": v, "shrink": 1 - v / base} for k, v in ref_scores.items()}
    # the choice: the pose diagnosis's engine on the usable voltages (:mod:`.transfer_engine`)
    progress("diagnosis: the empty tank's candidates through the diagnosis engine")
    engine, *heldout = diagnose_rows(empty_tank_problem(U, ok, V, cm, D, V2, fit.n_electrodes),
                                     noise=linear_floor(inj, np.where(ok, U, np.nan))["noise_rms_rel"],
                                     noise_source="the empty tank's linear floor per voltage, relative to its RMS; "
                                                  "it holds the channels' offsets too, so it is an upper bound")
    best_ref = engine["chosen"] or "unexplained"
    before, after = (np.full((P, M), np.nan) for _ in heldout)
    norm = float(np.sqrt(np.mean(U[ok] ** 2)))
    for grid, r in zip((before, after), heldout):
        grid[ok] = r * norm               # volts: measured - predicted, each held out
    where_ref = {"before": _where(before, np.where(ok, U, np.nan), mp, families),
                 "after": _where(after, np.where(ok, U, np.nan), mp, families)}
    # the tanks' changes, held out by tank
    tank_table, where_tanks = {}, {}
    blocks = [b for b in fit.problem.blocks if b.kind == "difference"]
    if blocks:
        progress("diagnosis: the tanks' changes, held out by tank")
        rows_y, rows_cols, rows_mask, rows_tank, rows_V2, rows_Vt = [], [], [], [], [], []
        for i, b in enumerate(blocks):
            Zt = fw.impedance(b.tank, geom, zeta)
            dV = s * volts(Zt - Z, b.injection, b.measurement_pattern)
            dV2 = s * volts(fw.impedance(b.tank, g2d, zeta) - fw.impedance("ref", g2d, zeta), b.injection,
                            b.measurement_pattern)
            rows_y.append(b.measured.ravel())
            rows_cols.append(dV)
            rows_V2.append(dV2)
            rows_Vt.append(s * volts(Zt, b.injection, b.measurement_pattern))
            rows_mask.append(b.mask.ravel())
            rows_tank.append(np.full(b.mask.size, i))
        y2 = np.concatenate(rows_y)
        m2 = np.concatenate(rows_mask)
        t2 = np.concatenate(rows_tank)
        meas = np.where(m2, y2, np.nan)
        dv = np.concatenate([c.ravel() for c in rows_cols])
        res = {"none": np.where(m2, y2 - dv, np.nan)}
        # channel gains fitted on the other tanks' changes
        G = np.vstack([_channel_columns(c, M) for c in rows_cols])
        res["channel_gains"] = heldout_linear(y2, G, m2, t2)
        res["2-D electrodes"] = np.where(m2, y2 - np.concatenate([c.ravel() for c in rows_V2]), np.nan)
        # the water's change since the reference: one scale per tank, each fold of its patterns scored with the
        # scale of the other fold (water_change)
        water = np.full(len(y2), np.nan)
        vt_all = np.concatenate([c.ravel() for c in rows_Vt])
        for i, b in enumerate(blocks):
            on = t2 == i
            shape = b.mask.shape
            water[on] = water_change(np.where(m2[on], y2[on] - dv[on], np.nan).reshape(shape),
                                     vt_all[on].reshape(shape), pattern_folds(shape[0]))["residual"].ravel()
        res["water_change"] = water
        for name, r in res.items():
            per = {b.tank: rms_rel(r[t2 == i], meas[t2 == i]) for i, b in enumerate(blocks)}
            tank_table[name] = {"heldout_rms_rel_by_tank": per, "median": float(np.median(list(per.values())))}
        b0 = tank_table["none"]["median"]
        for v in tank_table.values():
            v["shrink_of_median"] = 1 - v["median"] / b0
        for i, b in enumerate(blocks):
            where_tanks[b.tank] = _where(res["none"][t2 == i].reshape(P, M), meas[t2 == i].reshape(P, M), mp,
                                         families)
    ch = np.asarray(where_ref["before"]["by_channel_rel"])
    worst = np.argsort(-ch)[:3]
    metrics = {
        "empty_tank_candidates": ref_table, "empty_tank_chosen": best_ref, "empty_tank_engine": engine,
        "empty_tank_smallest_heldout": min(ref_scores, key=ref_scores.get),
        "empty_tank_where": where_ref,
        "tank_change_candidates": tank_table, "tank_change_where": where_tanks,
        "pattern_families": sorted(set(families)),
        "worst_channels": [{"channel": int(c) + 1, "rms_rel": float(ch[c])} for c in worst],
        "fitted_offsets_V": fit.offsets().tolist(),
    }
    return {"metrics": metrics, "arrays": {"ref_residual": ref_resid, "families": families,
                                          "angle_sensitivity": D}}
