"""Where the gap lies: the relative residual broken down by receiver, place, time and heading.

The residual is r = (bench - simulation) / |simulation|, one value per sample
and receiver. Each breakdown gives, per group, the number of values, the RMS,
the mean, the *share* of the total squared gap and the *enrichment*
(share / fraction of the values: 1 for a gap spread evenly, large where it
concentrates). Places are judged from the sensor's ends: within ``near_m`` of a
wall, the floor, the free surface or a known object, else ``mid_tank``.

Example
-------
>>> import numpy as np
>>> from electrosense.meshes.sensor import preset
>>> from electrosense.meshes.tank import Tank
>>> from electrosense.validation.diagnosis.observations import Observations
>>> x = np.linspace(-0.38, 0.38, 60)
>>> poses = np.column_stack([x, 0 * x, 0 * x, 0 * x])
>>> obs = Observations(poses, np.ones((60, 3)), preset("angels-4"), Tank((1, 1, 1)), 0.0354)
>>> r = np.where(np.abs(x)[:, None] > 0.3, 0.01, 0.0) * np.ones((60, 3))
>>> w = breakdown(obs, r)
>>> w["concentration"]["axis"], w["concentration"]["group"] in ("wall_x-", "wall_x+")
('place', True)
"""
from __future__ import annotations

import numpy as np

from electrosense.meshes.pose import sensor_to_tank
from electrosense.meshes.tank import TANK_REGIONS
from electrosense.validation.diagnosis.observations import Observations

__all__ = ["place_labels", "breakdown", "region_mask", "group_table"]


def place_labels(obs: Observations, near_m: float = 0.12) -> np.ndarray:
    """Label of each pose: the nearest tank boundary or known object within ``near_m``, else ``mid_tank``."""
    half = 0.5 * obs.sensor.length_m
    ends = np.array([[half, 0, 0], [0, 0, 0], [-half, 0, 0]])
    pts = sensor_to_tank(ends, obs.poses)  # (P, 3, 3)
    names, dists = [], []
    if obs.tank is not None:
        d = obs.tank.distance_to_boundary_m(pts).min(axis=1) - obs.sensor.radius_m  # (P, 6)
        names += list(TANK_REGIONS)
        dists.append(d)
    for k, o in enumerate(obs.objects, start=1):
        r = getattr(o, "bounding_radius_m", 0.0)
        d = np.linalg.norm(pts - np.asarray(o.centre_m), axis=-1).min(axis=1) - r - obs.sensor.radius_m
        names.append(f"object_{k}" if not getattr(o, "name", "") else f"object {o.name}")
        dists.append(d[:, None])
    labels = np.full(obs.n_poses, "mid_tank", dtype=object)
    if dists:
        D = np.concatenate(dists, axis=1)
        nearest = np.argmin(D, axis=1)
        close = D[np.arange(obs.n_poses), nearest] < near_m
        labels[close] = np.asarray(names, dtype=object)[nearest[close]]
    return labels


def group_table(r: np.ndarray, groups: np.ndarray, order=None) -> list[dict]:
    """Per group: n, rms, mean, share of the squared gap, fraction of values and enrichment.

    ``r`` (P, m); ``groups`` (P,) labels for rows or (P, m) labels per value.
    """
    g = np.broadcast_to(groups[:, None] if groups.ndim == 1 else groups, r.shape)
    total = float(np.sum(r**2))
    n_all = r.size
    keys = order if order is not None else sorted(set(g.ravel().tolist()), key=str)
    out = []
    for key in keys:
        sel = g == key
        n = int(sel.sum())
        if n == 0:
            continue
        v = r[sel]
        share = float(np.sum(v**2) / total) if total > 0 else 0.0
        frac = n / n_all
        out.append({
            "group": key if isinstance(key, str) else (int(key) if isinstance(key, (int, np.integer)) else key),
            "n": n, "rms": float(np.sqrt(np.mean(v**2))), "mean": float(np.mean(v)),
            "share": share, "fraction": frac, "enrichment": share / frac,
        })
    return out


def _time_trend(obs: Observations, r: np.ndarray) -> dict:
    t_h = (obs.t_s - obs.t_s.mean()) / 3600.0
    y = r.mean(axis=1)
    if np.ptp(t_h) == 0:
        return {"slope_per_hour": 0.0, "slope_stderr": float("inf")}
    A = np.column_stack([np.ones_like(t_h), t_h])
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    res = y - A @ coef
    s2 = float(res @ res) / max(len(y) - 2, 1)
    se = float(np.sqrt(s2 * np.linalg.inv(A.T @ A)[1, 1]))
    return {"slope_per_hour": float(coef[1]), "slope_stderr": se}


def breakdown(obs: Observations, r: np.ndarray, near_m: float = 0.12, n_time_bins: int = 5, min_fraction: float = 0.05,
              min_enrichment: float = 1.25) -> dict:
    """The residual ``r`` (P, m) broken down by receiver, place, time and heading, and where it concentrates.

    The concentration is the group (holding at least ``min_fraction`` of the
    values) with the largest enrichment; below ``min_enrichment`` the gap is
    called evenly spread (``axis`` and ``group`` "all").
    """
    r = np.asarray(r, float)
    P, m = r.shape
    receivers = np.broadcast_to(np.asarray(obs.sensor.receivers)[None, :], (P, m))
    out = {
        "n_values": int(r.size),
        "rms_relative": float(np.sqrt(np.mean(r**2))),
        "mean_relative": float(np.mean(r)),
        "by_receiver": group_table(r, receivers, order=list(obs.sensor.receivers)),
    }
    places = place_labels(obs, near_m)
    place_order = ["mid_tank"] + [p for p in dict.fromkeys(places.tolist()) if p != "mid_tank"]
    out["by_place"] = group_table(r, places, order=place_order)
    out["near_m"] = near_m
    # time: quantile bins, and the linear trend
    edges = np.quantile(obs.t_s, np.linspace(0, 1, n_time_bins + 1))
    tbin = np.clip(np.searchsorted(edges, obs.t_s, side="right") - 1, 0, n_time_bins - 1)
    tlabels = np.array([f"t {edges[k]:.0f}-{edges[k + 1]:.0f} s" for k in tbin], dtype=object)
    out["by_time"] = group_table(r, tlabels, order=[f"t {edges[k]:.0f}-{edges[k + 1]:.0f} s" for k in range(n_time_bins)])
    out["time_trend"] = _time_trend(obs, r)
    yaw = np.mod(obs.poses[:, 3] + np.pi / 8, 2 * np.pi)
    sector = (yaw // (np.pi / 4)).astype(int) % 8
    names = ["+x", "+x+y", "+y", "-x+y", "-x", "-x-y", "-y", "+x-y"]
    hlabels = np.array([f"heading {names[s]}" for s in sector], dtype=object)
    out["by_heading"] = group_table(r, hlabels, order=[f"heading {n}" for n in names])
    out["by_pass"] = group_table(r, np.array([f"pass {p}" for p in obs.passes], dtype=object),
                                 order=[f"pass {p}" for p in np.unique(obs.passes)])
    # where it concentrates: the group with the largest enrichment among those holding enough values
    best = None
    for axis in ("by_place", "by_receiver", "by_time", "by_heading"):
        table = out[axis]
        if len(table) < 2:
            continue
        for row in table:
            if row["fraction"] < min_fraction or row["fraction"] > 0.95:
                continue
            if best is None or row["enrichment"] > best["enrichment"]:
                best = {"axis": axis[3:], **row}
    if best is None or best["enrichment"] < min_enrichment:  # spread evenly: no region to speak of
        best = {"axis": "all", "group": "all", "n": int(r.size), "rms": out["rms_relative"], "mean": out["mean_relative"],
                "share": 1.0, "fraction": 1.0, "enrichment": 1.0}
    out["concentration"] = best
    out["labels"] = {"place": places, "time": tlabels, "heading": hlabels, "receiver": receivers}
    return out


def region_mask(where: dict) -> np.ndarray:
    """Boolean (P, m) mask of the values in the concentration region of :func:`breakdown`'s result."""
    c = where["concentration"]
    labels = where["labels"]
    rec = labels["receiver"]
    if c["axis"] == "all":
        return np.ones(rec.shape, bool)
    lab = labels[c["axis"]]
    lab = np.broadcast_to(lab[:, None] if lab.ndim == 1 else lab, rec.shape)
    return lab == c["group"]
