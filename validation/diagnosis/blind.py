"""Blind datasets for checking the diagnosis: effects built into a "world" simulation, withheld.

A *world* makes the bench data: the BEM with the effect in its scene (contact
impedance as its boundary condition, the object as a mesh, the other tank or
water depth as the tank mesh, the robot offset as the true poses), or, for
quick studies, the point-electrode stand-in. The diagnosis fits with another
code (the PSM as effect model), and is never told what was injected.

* :func:`blind_poses`: two realistic passes (wall to wall at mid-depth, and
  back along another line, a little turned and higher), with times.
* :data:`GEOMETRIC_TRUTH`: the geometric effects and their default strengths.
* :func:`world_currents`: noiseless receiver currents (P, m) per volt of a
  world with geometric effects.
* :func:`assemble`: bench observations from noiseless world currents: adds the
  output-side effects (conductivity, drift, channel gains), the bench noise
  (0.05 % on currents, 0.1 mm on logged positions) and logs the *nominal*
  poses.

Example
-------
>>> poses, t_s, passes = blind_poses(10)
>>> poses.shape, int(passes.max())
((20, 4), 1)
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from electrosense.meshes.objects import Sphere
from electrosense.meshes.sensor import SensorDescription, preset
from electrosense.meshes.tank import Tank
from electrosense.validation.diagnosis.forward import receiver_currents
from electrosense.validation.diagnosis.observations import Observations

__all__ = ["BlindSetup", "blind_poses", "GEOMETRIC_TRUTH", "world_scene", "world_currents", "assemble", "write_log",
           "CURRENT_NOISE", "POSITION_NOISE_M"]

CURRENT_NOISE = 5e-4  # relative, 1 sigma (the paper's 0.05 %)
POSITION_NOISE_M = 1e-4  # the robot's 0.1 mm


@dataclass(frozen=True)
class BlindSetup:
    """What the bench believes: sensor, tank, conductivity."""

    sensor: SensorDescription = field(default_factory=lambda: preset("angels-4"))
    tank: Tank = field(default_factory=lambda: Tank((1.0, 1.0, 1.0)))
    sigma_S_per_m: float = 0.0354


def blind_poses(n_per_pass: int = 30, dt_s: float = 10.0):
    """Two passes: y = 0, z = 0, yaw 0, x from -0.36 to 0.36; back at y = -0.15, z = 0.15, yaw 0.3, x 0.33 to -0.33."""
    x0 = np.linspace(-0.36, 0.36, n_per_pass)
    x1 = np.linspace(0.33, -0.33, n_per_pass)
    p0 = np.column_stack([x0, np.zeros_like(x0), np.zeros_like(x0), np.zeros_like(x0)])
    p1 = np.column_stack([x1, np.full_like(x1, -0.15), np.full_like(x1, 0.15), np.full_like(x1, 0.3)])
    poses = np.vstack([p0, p1])
    t = np.arange(len(poses)) * dt_s
    t[n_per_pass:] += 60.0  # the robot returns
    passes = np.repeat([0, 1], n_per_pass)
    return poses, t, passes


#: geometric effects built into the world's scene (default strengths)
GEOMETRIC_TRUTH = {
    "contact_impedance": {"z_c_ohm_m2": 0.003},
    "pose_offset": {"dx_m": 0.01, "dy_m": -0.008, "dyaw_rad": 0.04},
    "water_depth": {"water_depth_m": 0.8},
    "tank_size": {"Lx_m": 0.97},
    "unmodelled_object": {"centre_m": (0.1, 0.075, 0.0), "radius_m": 0.04, "material": "conducting"},
}

def world_scene(setup: BlindSetup, poses: np.ndarray, effect: str | None, strength: dict | None = None):
    """(true poses, tank, objects, contact impedance) of a world with one geometric effect."""
    s = dict(GEOMETRIC_TRUTH.get(effect, {}), **(strength or {}))
    poses = np.array(poses, float)
    tank, objects, z = setup.tank, (), None
    if effect in (None, "none"):
        pass
    elif effect == "contact_impedance":
        z = float(s["z_c_ohm_m2"])
    elif effect == "pose_offset":
        c, sn = np.cos(s["dyaw_rad"]), np.sin(s["dyaw_rad"])
        x, y = poses[:, 0].copy(), poses[:, 1].copy()
        poses[:, 0] = c * x - sn * y + s["dx_m"]
        poses[:, 1] = sn * x + c * y + s["dy_m"]
        poses[:, 3] += s["dyaw_rad"]
    elif effect == "water_depth":
        tank = Tank(setup.tank.size_m, float(s["water_depth_m"]))
    elif effect == "tank_size":
        lx, ly, lz = setup.tank.size_m
        tank = Tank((float(s["Lx_m"]), ly, lz), setup.tank.water_depth_m)
    elif effect == "unmodelled_object":
        material = np.inf if s["material"] == "conducting" else 0.0
        objects = (Sphere(tuple(s["centre_m"]), conductivity_S_per_m=material, radius_m=float(s["radius_m"])),)
    else:
        raise ValueError(f"{effect!r} is not a geometric effect of the blind worlds")
    return poses, tank, objects, z


def world_currents(world, setup: BlindSetup, poses: np.ndarray, effect: str | None, strength: dict | None = None):
    """Noiseless receiver currents per volt (P, m) of ``world(poses, tank, objects, z_c) -> K``."""
    true_poses, tank, objects, z = world_scene(setup, poses, effect, strength)
    K = world(true_poses, tank, objects, z)
    return receiver_currents(K, setup.sensor.emitter)


def assemble(
    setup: BlindSetup, poses, t_s, passes, I_world, rng, conductivity: float = 0.0, drift_per_hour: float = 0.0,
    gains=None, log_temperature: bool = False, alpha_per_K: float = 0.02, U_V: float = 1.0,
    current_noise: float = CURRENT_NOISE, position_noise_m: float = POSITION_NOISE_M,
) -> Observations:
    """Bench observations from noiseless world currents ``I_world`` (P, m), with output-side effects and noise.

    The logged poses are ``poses`` (the believed ones) plus position noise;
    the water's conductivity is ``sigma (1 + conductivity) (1 + drift (t - t_mean))``;
    with ``log_temperature`` a ``temp_C`` column follows the drift at
    ``alpha_per_K`` (plus 0.01 K noise).
    """
    poses = np.asarray(poses, float)
    t_s = np.asarray(t_s, float)
    scale = (1 + conductivity) * (1 + drift_per_hour * (t_s - t_s.mean()) / 3600.0)
    I = I_world * scale[:, None] * U_V
    if gains is not None:
        I = I * (1 + np.asarray(gains, float))[None, :]
    I = I * (1 + current_noise * rng.standard_normal(I.shape))
    logged = poses.copy()
    logged[:, :3] += position_noise_m * rng.standard_normal((len(poses), 3))
    temp = None
    meta = {"sensor": setup.sensor.name, "emitter": setup.sensor.emitter, "tank_m": list(setup.tank.size_m),
            "water_depth_m": setup.tank.water_depth_m, "sigma_S_per_m": setup.sigma_S_per_m, "voltage_V": U_V}
    if log_temperature:
        meta["temperature_C"] = 20.0
        temp = 20.0 + drift_per_hour * (t_s - t_s.mean()) / 3600.0 / alpha_per_K + 0.01 * rng.standard_normal(len(t_s))
    return Observations(logged, I, setup.sensor, setup.tank, setup.sigma_S_per_m, U_V=np.full(len(poses), U_V),
                        t_s=t_s, passes=passes, temperature_C=temp, meta=meta, source="blind")


def write_log(obs: Observations, path, overwrite: bool = True):
    """Write blind observations as a bench log (format version 1), passes and temperature included."""
    from electrosense.validation.bench.log import write_bench_log

    data = {"t_s": obs.t_s, "x_m": obs.poses[:, 0], "y_m": obs.poses[:, 1], "z_m": obs.poses[:, 2],
            "yaw_rad": obs.poses[:, 3], "U_V": obs.U_V}
    for j, k in enumerate(obs.sensor.receivers):
        data[f"I{k}_A"] = obs.currents_A[:, j]
    if obs.temperature_C is not None:
        data["temp_C"] = obs.temperature_C
    data["pass"] = obs.passes
    return write_bench_log(path, dict(obs.meta), data, overwrite=overwrite)
