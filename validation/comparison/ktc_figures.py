"""Figures of the KTC study: the tanks with their objects, measured against predicted change by pattern, the gap by
electrode, and what each candidate effect explains."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from electrosense.validation.report.style import CYCLE, new_figure, save

__all__ = ["all_figures", "tanks_figure", "change_figure", "gap_by_electrode_figure", "candidates_figure"]

_MATERIAL = {True: ("#d9541a", "metal"), False: ("#1f5fbf", "plastic")}


def _draw_tank(ax, geom, objects, truth=None, out_of_use=(), title=""):
    R = geom.radius_m
    if truth is not None:
        n = truth.mask.shape[0]
        half = 0.5 * truth.side_m
        shown = np.ma.masked_equal(truth.mask, 0)
        ax.imshow(shown, extent=(-half, half, -half, half), origin="upper", cmap="Greys", vmin=0, vmax=3,
                  interpolation="nearest", alpha=0.6)
        del n
    t = np.linspace(0, 2 * np.pi, 400)
    ax.plot(R * np.cos(t), R * np.sin(t), color="0.3", lw=0.8)
    for k, e in enumerate(geom.electrodes(), start=1):
        a = np.linspace(e.phi_start_rad, e.phi_end_rad, 12)
        c = "#b0b0b0" if k in out_of_use else "#2ca02c"
        ax.plot(1.03 * R * np.cos(a), 1.03 * R * np.sin(a), color=c, lw=3, solid_capstyle="butt")
        if (k - 1) % 8 == 0:
            ax.text(1.16 * R * math.cos(e.phi_centre_rad), 1.16 * R * math.sin(e.phi_centre_rad), str(k),
                    ha="center", va="center", fontsize=7)
    for o in objects:
        p = np.vstack([o.polygon_m, o.polygon_m[:1]]) + np.asarray(geom.frame_shift_m)
        col, _ = _MATERIAL[o.is_conducting]
        ax.plot(p[:, 0], p[:, 1], color=col, lw=1.2)
    ax.set_aspect("equal")
    ax.set_xlim(-1.25 * R, 1.25 * R)
    ax.set_ylim(-1.25 * R, 1.25 * R)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(title, fontsize=8)


def tanks_figure(path, geom, tanks: dict) -> Path:
    """One panel per tank: the truth mask (grey), the traced prisms (blue plastic, orange metal), the electrodes at
    their fitted arc and rotation (green; grey out of use), numbered every eighth."""
    n = max(1, len(tanks))
    cols = min(4, n)
    rows = int(math.ceil(n / cols))
    fig, axes = new_figure(rows, cols, panel_size_in=(2.6, 2.6))
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    for ax, (name, (objs, truth, out)) in zip(axes.ravel(), tanks.items()):
        _draw_tank(ax, geom, objs, truth, out, name)
    return save(fig, path)


def change_figure(path, predictions: dict, patterns=None) -> Path | None:
    """Measured (dots) against predicted (line) change by pattern, one panel per tank, the first patterns' channels
    in order; the residual in grey."""
    items = [(k, r) for k, r in predictions.items() if "metrics" in r][:8]
    if not items:
        return None
    fig, axes = new_figure(len(items), 1, panel_size_in=(7.0, 1.9))
    for ax, (name, r) in zip(axes[:, 0], items):
        meas, pred = r["measured"], r["predicted"]
        P, M = meas.shape
        sel = list(range(min(P, 16))) if patterns is None else list(patterns)
        y_m = 1e3 * meas[sel].ravel()
        y_p = 1e3 * pred[sel].ravel()
        x = np.arange(len(y_m))
        ax.plot(x, y_p, color=CYCLE[0], lw=0.8, label="predicted")
        ax.plot(x, y_m, ".", color=CYCLE[1], ms=2.0, label="measured")
        ax.plot(x, y_m - y_p, color="0.6", lw=0.6, label="measured - predicted")
        for p in range(1, len(sel)):
            ax.axvline(p * M - 0.5, color="0.9", lw=0.5, zorder=0)
        ax.set_ylabel("change (mV)")
        m = r["metrics"]
        ax.set_title(f"{name}: RMS of the gap {100 * m['difference_rms_rel']:.1f} % of the change "
                     f"(floor {100 * m['difference_floor_rel']:.1f} %); patterns {sel[0] + 1}-{sel[-1] + 1}, "
                     f"{M} channels each", fontsize=8)
    axes[0, 0].legend(fontsize=7, loc="upper right", ncol=3)
    axes[-1, 0].set_xlabel("pattern after pattern, channel after channel")
    return save(fig, path)


def gap_by_electrode_figure(path, diag_metrics: dict, predictions: dict, measurement_pattern) -> Path:
    """The gap's RMS by electrode: the empty tank held out by pattern (the scene alone, and with the chosen
    effect), and each predicted tank's change."""
    from electrosense.validation.diagnosis.ktc_gap import by_electrode

    fig, axes = new_figure(2, 1, panel_size_in=(7.0, 2.2))
    w = diag_metrics["empty_tank_where"]
    e = np.arange(1, len(w["before"]["by_electrode_rel"]) + 1)
    ax = axes[0, 0]
    ax.bar(e - 0.2, 100 * np.asarray(w["before"]["by_electrode_rel"]), 0.4, color=CYCLE[1], label="scene alone")
    ax.bar(e + 0.2, 100 * np.asarray(w["after"]["by_electrode_rel"]), 0.4, color=CYCLE[0],
           label=(f"with {diag_metrics['empty_tank_chosen']}" if diag_metrics["empty_tank_chosen"] != "unexplained"
                  else "with the nearest, not named: " + diag_metrics.get("empty_tank_engine", {}).get("combination", "?")))
    ax.set_ylabel("RMS gap (% of RMS V)")
    ax.set_title("empty tank, held-out patterns: the gap on the channels that read each electrode", fontsize=8)
    ax.legend(fontsize=7)
    ax = axes[1, 0]
    items = [(k, r) for k, r in predictions.items() if "metrics" in r][:6]
    width = 0.8 / max(1, len(items))
    for i, (name, r) in enumerate(items):
        den = float(np.sqrt(np.nanmean(r["measured"] ** 2)))
        g = by_electrode(r["predicted"] - r["measured"], measurement_pattern) / den
        ax.bar(e - 0.4 + (i + 0.5) * width, 100 * g, width, color=CYCLE[i % len(CYCLE)], label=name)
    ax.set_xlabel("electrode")
    ax.set_ylabel("RMS gap (% of RMS change)")
    ax.set_title("predicted tanks: the gap of the change by electrode", fontsize=8)
    if items:
        ax.legend(fontsize=6, ncol=3)
    for a in axes[:, 0]:
        a.set_xticks(e[::2])
    return save(fig, path)


def candidates_figure(path, diag_metrics: dict, ref_floor: float) -> Path:
    """What each candidate effect leaves, held out: on the empty tank (by pattern) beside its linear floor, and on
    the tanks' changes (by tank, median)."""
    fig, axes = new_figure(1, 2, panel_size_in=(3.6, 2.6))
    c = diag_metrics["empty_tank_candidates"]
    names = list(c)
    ax = axes[0, 0]
    ax.barh(range(len(names)), [100 * c[n]["heldout_rms_rel"] for n in names], color=CYCLE[0])
    ax.axvline(100 * ref_floor, color="k", ls="--", lw=0.8, label="linear floor")
    ax.axvline(150 * ref_floor, color="0.5", ls=":", lw=0.8, label="1.5 x floor")
    ax.set_yticks(range(len(names)), names, fontsize=7)
    ax.set_xlabel("held-out RMS (% of RMS V)")
    ax.set_title("empty tank, held out by pattern", fontsize=8)
    ax.legend(fontsize=6, loc="center right")     # the middle bars are the short ones
    ax = axes[0, 1]
    t = diag_metrics.get("tank_change_candidates", {})
    if t:
        names = list(t)
        ax.barh(range(len(names)), [100 * t[n]["median"] for n in names], color=CYCLE[1])
        ax.set_yticks(range(len(names)), names, fontsize=7)
        ax.set_xlabel("median RMS (% of the change)")
        ax.set_title("tanks' change, held out by tank", fontsize=8)
    else:
        ax.set_visible(False)
    return save(fig, path)


def all_figures(out: Path, metrics, fit, fit_folder, predictions, diag) -> list[Path]:
    from electrosense.validation.bench.transfer.ktc_mat import usable

    paths = []
    geom = fit.geometry()
    tanks = {}
    for name, r in predictions.items():
        if "metrics" in r:
            tanks[name] = (r["objects"], r["truth"], r["metrics"]["electrodes_out_of_use"])
    if not tanks:
        for name, (d, t) in fit_folder.tanks.items():
            tanks[name] = (fit.forward.objects[name], t, usable(d)[1])
    paths.append(tanks_figure(out / "tanks.png", geom, tanks))
    p = change_figure(out / "change_by_pattern.png", predictions)
    if p is not None:
        paths.append(p)
    if diag is not None:
        paths.append(gap_by_electrode_figure(out / "gap_by_electrode.png", diag["metrics"], predictions,
                                             fit_folder.ref.measurement_pattern))
        paths.append(candidates_figure(out / "candidates.png", diag["metrics"], metrics["ref_linear_floor_rel"]))
    return paths
