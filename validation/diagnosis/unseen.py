"""Set-ups the diagnosis has never seen: random sensors, tanks, depths, conductivities and passes.

The blind checks of the diagnosis must not run on the presets in the 1 m
cube alone (anything tuned to them would pass). :func:`random_setup` draws a
sensor (3 to 6 electrodes: two end caps and rings between, random radius,
length, electrode extents and emitter), a box tank of random proportions,
partly filled, and a conductivity; :func:`random_passes` draws passes the
bench can make in it (straight lines at random depth and heading, reaching to
a couple of centimetres of the walls).

Example
-------
>>> import numpy as np
>>> setup = random_setup(np.random.default_rng(1), n_electrodes=5)
>>> setup.sensor.n_electrodes, setup.tank.water_depth_m < setup.tank.size_m[2]
(5, True)
>>> poses, t_s, passes = random_passes(setup, np.random.default_rng(2), n_passes=3, per_pass=11)
>>> poses.shape, int(passes.max())
((33, 4), 2)
"""
from __future__ import annotations

import numpy as np

from electrosense.meshes.pose import sensor_to_tank
from electrosense.meshes.sensor import Electrode, SensorDescription
from electrosense.meshes.tank import Tank
from electrosense.validation.diagnosis.blind import BlindSetup

__all__ = ["random_sensor", "random_setup", "random_passes"]


def random_sensor(rng, n_electrodes: int | None = None, name: str = "unseen") -> SensorDescription:
    """A sensor of 3-6 electrodes (or ``n_electrodes``): two caps, rings evenly spread with random widths."""
    n = int(rng.integers(3, 7)) if n_electrodes is None else int(n_electrodes)
    radius = float(rng.uniform(0.008, 0.016))
    length = float(rng.uniform(0.14, 0.26))
    half = 0.5 * length
    cap = float(rng.uniform(0.5, 0.9)) * radius
    electrodes = [Electrode("cap", half - cap, half)]
    n_rings = n - 2
    if n_rings:
        span = half - radius - 0.004  # rings stay off the hemispheres
        centres = np.linspace(span, -span, n_rings + 2)[1:-1] + rng.uniform(-0.15, 0.15, n_rings) * (2 * span / (n_rings + 1))
        gap = 2 * span / (n_rings + 1)
        for c in centres:
            w = float(rng.uniform(0.2, 0.45)) * gap
            electrodes.append(Electrode("ring", float(c - w / 2), float(c + w / 2)))
    electrodes.append(Electrode("cap", -half, -half + cap))
    emitter = int(rng.integers(1, n + 1))
    return SensorDescription(name=name, radius_m=radius, length_m=length, electrodes=tuple(electrodes), emitter=emitter)


def random_setup(rng, n_electrodes: int | None = None) -> BlindSetup:
    """A random sensor in a random, partly filled box tank at a random conductivity."""
    lx, ly = rng.uniform(0.6, 1.2), rng.uniform(0.45, 0.9)
    lz = rng.uniform(0.35, 0.7)
    tank = Tank((float(lx), float(ly), float(lz)), float(lz * rng.uniform(0.7, 0.95)))
    sigma = float(np.exp(rng.uniform(np.log(0.01), np.log(0.1))))
    return BlindSetup(random_sensor(rng, n_electrodes), tank, sigma)


def random_passes(setup: BlindSetup, rng, n_passes: int = 3, per_pass: int = 41, wall_gap_m: float = 0.015,
                  dt_s: float = 5.0):
    """``n_passes`` straight passes of ``per_pass`` poses: (poses (P, 4), t_s (P,), passes (P,)).

    Pass 0 runs along x at mid-height of the water from ``wall_gap_m`` off one
    end wall to as close to the other (the wall-to-wall pass a bench makes);
    the others run at a random heading, depth and offset, clipped so that the
    sensor's tips (on its axis) stay ``wall_gap_m`` away from every boundary.
    """
    tank, s = setup.tank, setup.sensor
    lo, hi = tank.water_bounds_m
    mid_z = 0.5 * (lo[2] + hi[2])
    tips = np.array([[0.5 * s.length_m, 0, 0], [-0.5 * s.length_m, 0, 0]])
    margin = wall_gap_m
    out, times, labels, t0 = [], [], [], 0.0
    for k in range(n_passes):
        if k == 0:
            yaw, y, z = 0.0, 0.0, mid_z
        else:
            yaw = float(rng.uniform(-0.6, 0.6)) + (np.pi / 2 if rng.random() < 0.3 else 0.0)
            y = float(rng.uniform(-0.2, 0.2) * (hi[1] - lo[1]))
            z = float(rng.uniform(lo[2] + 0.3 * (hi[2] - lo[2]), hi[2] - 0.3 * (hi[2] - lo[2])))
        d = np.array([np.cos(yaw), np.sin(yaw)])
        # longest segment along d through (0, y) with the tips inside by margin: scan and keep the feasible part
        u = np.linspace(-2.0, 2.0, 4001)
        P = np.column_stack([u * d[0], y + u * d[1], np.full_like(u, z), np.full_like(u, yaw)])
        ends = sensor_to_tank(tips, P)  # (U, 2, 3)
        inside = np.all(tank.distance_to_boundary_m(ends) >= margin, axis=(1, 2))
        if not inside.any():
            raise ValueError(f"pass {k}: the sensor does not fit in the tank with {wall_gap_m} m to spare")
        i = np.flatnonzero(inside)
        u_line = np.linspace(u[i[0]], u[i[-1]], per_pass)
        if k % 2:
            u_line = u_line[::-1]
        out.append(np.column_stack([u_line * d[0], y + u_line * d[1], np.full(per_pass, z), np.full(per_pass, yaw)]))
        times.append(t0 + dt_s * np.arange(per_pass))
        t0 = times[-1][-1] + 60.0
        labels.append(np.full(per_pass, k))
    return np.vstack(out), np.concatenate(times), np.concatenate(labels)
