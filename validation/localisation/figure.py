"""The figure of ``esense localise``: the tracks from the currents over the logged one, and their errors against the
Cramer-Rao bound."""
from __future__ import annotations

import numpy as np

__all__ = ["track_figure"]

LABEL = {"map": "tank map", "psm": "PSM"}


def track_figure(obs, res: dict, png_path):
    """Two panels: the tank from above with the logged track and each model's; position error along the log with
    each model's Cramer-Rao bound."""
    from electrosense.validation.report.style import colour_of, new_figure, save

    fig, axes = new_figure(1, 2, panel_size_in=(4.2, 3.4))
    ax, bx = axes[0]
    lo, hi = obs.tank.water_bounds_m
    if hasattr(obs.tank, "radius_m"):
        th = np.linspace(0, 2 * np.pi, 200)
        ax.plot(obs.tank.radius_m * np.cos(th), obs.tank.radius_m * np.sin(th), color="0.4", lw=1)
    else:
        ax.plot([lo[0], hi[0], hi[0], lo[0], lo[0]], [lo[1], lo[1], hi[1], hi[1], lo[1]], color="0.4", lw=1)
    ax.plot(obs.poses[:, 0], obs.poses[:, 1], color="k", lw=2.5, label="logged", zorder=1)
    i = np.arange(obs.n_poses)
    for k, name in enumerate(("map", "psm")):
        est = res["tracks"][name]
        s = res[name]
        c = colour_of(name, k)
        ax.plot(est[:, 0], est[:, 1], ".", ms=3, color=c, label=f"{LABEL[name]} from the currents", zorder=2)
        d = np.linalg.norm(est[:, :2] - obs.poses[:, :2], axis=1)
        bx.semilogy(i, np.maximum(d, 1e-7) * 1e3, ".", ms=3, color=c,
                    label=f"{LABEL[name]}: {1e3 * s['position_rms_m']:.3g} mm RMS")
        if s.get("_crb_position_m") is not None:
            bx.semilogy(i, s["_crb_position_m"] * 1e3, "-", lw=1, color=c,
                        label=f"{LABEL[name]} bound: {1e3 * s['crb_position_rms_m']:.3g} mm RMS")
        if res.get("motion") is not None and s.get("_crb_per_sample_position_m") is not None:
            bx.semilogy(i, s["_crb_per_sample_position_m"] * 1e3, ":", lw=1, color=c,
                        label=f"{LABEL[name]} per-sample bound: {1e3 * s['crb_per_sample_position_rms_m']:.3g} mm")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("tank from above")
    ax.legend(loc="best", fontsize=7)
    bx.set_xlabel("sample")
    bx.set_ylabel("position error (mm)")
    how = "each sample alone" if res.get("motion") is None else "whole track, motion prior"
    bx.set_title(f"error and Cramer-Rao bound\n({how}; noise {100 * res['noise_rel']:.3f} %)", fontsize=9)
    # below the panel: inside, it covered the bounds' ends wherever it went
    bx.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2, fontsize=6, frameon=False)
    return save(fig, png_path, vector=None)
