"""The diagnosis's baseline from a tank map: the map's K at the logged poses, with its estimated error.

A tank map (:mod:`electrosense.validation.simulation.tank_map`) is the BEM over every pose of one sensor in
one tank, interpolated, with its own error estimated everywhere. Given one, a log in that tank needs no new BEM:
the baseline is the map at the logged poses, and its estimated error enters the noise floor and the samples'
weights exactly as the anchored baseline's does (the returned object is an
:class:`~electrosense.validation.diagnosis.anchored.AnchoredBaseline` with no BEM pose of its own).

Example
-------
>>> baseline = map_baseline(obs, load_tank_map("tank.map.npz"))  # doctest: +SKIP
>>> diagnose(obs, baseline=baseline)  # doctest: +SKIP
"""
from __future__ import annotations

import time

import numpy as np

__all__ = ["map_baseline"]


def map_baseline(obs, tank_map, target_factor: float = 1.0 / 3.0, noise: float | None = None):
    """The :class:`~electrosense.validation.diagnosis.anchored.AnchoredBaseline` of ``obs`` from ``tank_map``;
    refuses a map of another sensor, tank or objects, and logged poses it does not cover."""
    from electrosense.validation.diagnosis.anchored import AnchoredBaseline
    from electrosense.validation.simulation.tank_map import log_in_map_scene

    t0 = time.perf_counter()
    obs = log_in_map_scene(tank_map, obs)
    inside, why = tank_map.covers(obs.poses)
    if not inside.all():
        raise ValueError(f"the map does not cover the log: {why}")
    K = tank_map.conductance(obs.poses, obs.sigma_S_per_m)
    error = tank_map.estimated_error(obs.poses)
    loo = tank_map.leave_one_out
    from electrosense.validation.defaults import BENCH_CURRENT_NOISE_REL

    return AnchoredBaseline(
        K=K, error=error, anchors=np.zeros(0, int), refused=np.zeros(0, int), n_bem_new=0,
        n_cached=int(len(tank_map.nodes)), target=target_factor * (noise or BENCH_CURRENT_NOISE_REL),
        rounds=list(tank_map.history), psm_vs_bem_rms=float("nan"), loo_rms=float(np.sqrt(np.mean(loo**2))),
        seconds=time.perf_counter() - t0, base="map",
    )
