"""The figure of ``esense localise``: the tracks from the currents over the logged one, their errors against the
Cramer-Rao bound, and, where the run looked for an object, the object each model found beside the true one."""
from __future__ import annotations

import numpy as np

__all__ = ["track_figure", "object_panel"]

LABEL = {"map": "tank map", "psm": "PSM"}


def track_figure(obs, res: dict, png_path):
    """Two panels: the tank from above with the logged track and each model's; position error along the log with
    each model's Cramer-Rao bound. A third where ``res`` holds an object search (:func:`object_panel`)."""
    from electrosense.validation.report.style import colour_of, new_figure, save

    found = res.get("object")
    fig, axes = new_figure(1, 3 if found else 2, panel_size_in=(4.2, 3.4))
    ax, bx = axes[0][:2]
    if found:
        object_panel(axes[0][2], obs, found)
    lo, hi = obs.tank.water_bounds_m
    if hasattr(obs.tank, "radius_m"):
        th = np.linspace(0, 2 * np.pi, 200)
        ax.plot(obs.tank.radius_m * np.cos(th), obs.tank.radius_m * np.sin(th), color="0.4", lw=1)
    else:
        ax.plot([lo[0], hi[0], hi[0], lo[0], lo[0]], [lo[1], lo[1], hi[1], hi[1], lo[1]], color="0.4", lw=1)
    ax.plot(obs.poses[:, 0], obs.poses[:, 1], color="k", lw=2.5, label="logged", zorder=1)
    i = np.arange(obs.n_poses)
    for k, name in enumerate(("map", "psm")):
        if name not in res["tracks"]:    # no PSM in a cylindrical tank
            continue
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
    if found and found.get("true_centre_m") is not None:
        ax.plot(*found["true_centre_m"][:2], "x", color="k", ms=6, label="the object (true centre)")
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


def object_panel(ax, obs, found: dict, half_width_m: float = 0.04):
    """The object search of ``esense localise`` close up: the logged path, each model's sphere (its fitted radius)
    with the 95 % ellipse of its centre (chi-square(2) of the covariance's (x, y) block), an alternative the data
    do not separate from it, and the true centre where known; a model that detected nothing is said in the
    legend."""
    import matplotlib.patches as mpatches

    from electrosense.validation.report.style import colour_of

    fits = {name: found[name] for name in LABEL if name in found}
    true = found.get("true_centre_m")
    # the view: the true centre, else the map's sphere, else the path's middle (a comparison model's detection,
    # the PSM's own error hundreds of mm off, does not steer it: it is said "off this view")
    first = next(iter(fits.values()), None)
    centre = np.asarray(true[:2] if true is not None else first["centre_m"][:2] if first and first["detected"]
                        else obs.poses[len(obs.poses) // 2, :2])
    # wide enough to show where the path passes it
    half_width_m = max(half_width_m, 0.01 + float(np.min(np.abs(obs.poses[:, :2] - centre).max(axis=1))))
    inside = lambda xy: bool(np.all(np.abs(np.asarray(xy) - centre) < half_width_m))   # noqa: E731
    ax.plot(1e3 * obs.poses[:, 0], 1e3 * obs.poses[:, 1], color="k", lw=1, label="logged path (sensor centre)",
            zorder=1)
    for k, (name, f) in enumerate(fits.items()):
        c = colour_of(name, k)
        if not f["detected"]:
            ax.plot([], [], " ", label=f"{LABEL[name]}: none detected ({f['statistic']:.3g} <= {f['threshold']:.3g})")
            continue
        x, y = f["centre_m"][:2]
        r = f["radius_m"] or 0.0
        ax.add_patch(mpatches.Circle((1e3 * x, 1e3 * y), 1e3 * r, fill=False, color=c, lw=1.2))
        cov = np.asarray(f.get("crb_cov_xy_m2", np.full((2, 2), np.nan)), float)
        if np.all(np.isfinite(cov)):
            w, v = np.linalg.eigh(cov)
            a, b = 2e3 * np.sqrt(5.991 * np.maximum(w, 0.0))
            angle = np.degrees(np.arctan2(v[1, 1], v[0, 1]))
            ax.add_patch(mpatches.Ellipse((1e3 * x, 1e3 * y), a, b, angle=angle, fill=True, alpha=0.25, color=c))
        bound = f["crb_position_rms_m"]
        ax.plot(1e3 * x, 1e3 * y, "+", color=c, ms=7, label=f"{LABEL[name]}: sphere of {1e3 * r:.3g} mm"
                + (f", 95 % region ({1e3 * bound:.2g} mm RMS bound)" if np.isfinite(bound)
                   else ", bound not determined")
                + ("" if inside((x, y)) else f", at ({1e3 * x:.0f}, {1e3 * y:.0f}) mm: off this view"))
        alt = f.get("alternative_centre_m")
        if alt is not None and f.get("alternative_chi2_excess", np.inf) < 3.84:
            ax.plot(1e3 * alt[0], 1e3 * alt[1], "o", mfc="none", color=c, ms=5,
                    label=f"{LABEL[name]}: not separated from it")
    if true is not None:
        ax.plot(1e3 * true[0], 1e3 * true[1], "x", color="k", ms=7, label="true centre")
    ax.set_xlim(1e3 * (centre[0] - half_width_m), 1e3 * (centre[0] + half_width_m))
    ax.set_ylim(1e3 * (centre[1] - half_width_m), 1e3 * (centre[1] + half_width_m))
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(f"an object the log passes, at z = {found['z_m']:.3g} m", fontsize=9)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=1, fontsize=6, frameon=False)
