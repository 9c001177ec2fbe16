"""The virtual bench's physics: what the sensor really measures along a trajectory.

The logged pose is the robot's nominal pose; the sensor really sits at the
nominal pose plus the pose-offset effect plus the robot's imprecision
(Gaussian, 0.1 mm on x, y, z). The model (``"psm"`` or ``"bem"``, through
:func:`electrosense.validation.simulation.models.simulate`) is evaluated there, in the true tank and
water, with the unmodelled object and the contact impedance; then the
temperature drift scales the conductivity in time, the channel gains
multiply, and the current measurement adds its 0.05 % relative noise.

Example
-------
>>> from electrosense.meshes.sensor import preset
>>> from electrosense.meshes.tank import Tank
>>> from electrosense.validation.bench.virtual.bench import VirtualBench
>>> from electrosense.validation.bench.virtual.trajectory import wall_to_wall
>>> bench = VirtualBench(preset("angels-4"), Tank((1, 1, 1)), 0.0354, model="psm")     # doctest: +SKIP
>>> run = bench.run(wall_to_wall(), rate_hz=10.0)                                     # doctest: +SKIP
>>> run.currents_A.shape                                                              # doctest: +SKIP
(161, 3)
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from electrosense.meshes.sensor import SensorDescription
from electrosense.meshes.tank import Tank
from electrosense.validation.bench.log.header import receiver_columns
from electrosense.validation.bench.virtual.effects import TEMPERATURE_COEFFICIENT_PER_K, Effects
from electrosense.validation.defaults import BENCH_CURRENT_NOISE_REL, BENCH_POSITION_NOISE_M

__all__ = ["BenchNoise", "VirtualBench", "SimulatedRun", "SIMULATOR_LABEL"]

SIMULATOR_LABEL = "esense bench-sim: SIMULATED data from the virtual bench, not a measurement"


@dataclass(frozen=True)
class BenchNoise:
    """The bench's imprecision: relative current noise and robot position noise (1 sigma)."""

    current_rel: float = BENCH_CURRENT_NOISE_REL   # the paper: 0.05 % relative precision of the current
    position_m: float = BENCH_POSITION_NOISE_M     # the paper: 0.1 mm precision of the cartesian robot


@dataclass
class SimulatedRun:
    """Every sample of a virtual bench run, nominal and true.

    Arrays have one row per sample: ``t_s`` (P,), ``poses`` (P, 4) logged,
    ``true_poses`` (P, 4), ``U_V`` (P,), ``currents_A`` (P, n-1) measured,
    ``temp_C`` (P,), ``sigma_true_S_per_m`` (P,), ``passes`` (P,).
    """

    t_s: np.ndarray
    poses: np.ndarray
    true_poses: np.ndarray
    U_V: np.ndarray
    currents_A: np.ndarray
    temp_C: np.ndarray
    sigma_true_S_per_m: np.ndarray
    passes: np.ndarray
    sensor: SensorDescription
    info: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.t_s)

    @property
    def columns(self) -> tuple[str, ...]:
        """Bench-log columns of a record: t_s, pose, U_V, receiver currents, temp_C, pass."""
        return ("t_s", "x_m", "y_m", "z_m", "yaw_rad", "U_V") + receiver_columns(self.sensor) + ("temp_C", "pass")

    def record_values(self, i: int, t_s: float | None = None) -> list[str]:
        """Sample ``i`` as the device formats it (0.1 mm on positions, 6 significant digits on currents)."""
        t = self.t_s[i] if t_s is None else t_s
        x, y, z, yaw = self.poses[i]
        return ([f"{t:.3f}", f"{x:.4f}", f"{y:.4f}", f"{z:.4f}", f"{yaw:.6f}", f"{self.U_V[i]:.6f}"]
                + [f"{c:.5e}" for c in self.currents_A[i]] + [f"{self.temp_C[i]:.2f}", str(int(self.passes[i]))])


class VirtualBench:
    """A tank, water and a sensor on a robot, with the bench's noise and optional physical effects.

    Parameters
    ----------
    sensor : SensorDescription
        With its emitter.
    tank : Tank or None
        The nominal tank (what the log's meta says).
    sigma_S_per_m : float
        Nominal conductivity (what the log's meta says).
    model : {"bem", "psm"}
        The physics: the BEM by default (see :meth:`_currents_A`), the PSM
        only when asked (it is the diagnosis's fast path: data made with it
        cannot test it).
    psm_model : PolySphericalModel or path, optional
    effects : Effects
    noise : BenchNoise
    temperature_C : float
        Water temperature at the start.
    seed : int, optional
    simulate : callable, optional
        Stand-in for :func:`electrosense.validation.simulation.models.simulate` (same signature),
        e.g. in tests.
    """

    def __init__(self, sensor: SensorDescription, tank: Tank | None, sigma_S_per_m: float, model: str = "bem",
                 psm_model=None, effects: Effects = Effects(), noise: BenchNoise = BenchNoise(),
                 temperature_C: float = 20.0, seed: int | None = None, simulate=None, **model_options):
        self.sensor, self.tank, self.sigma_S_per_m = sensor, tank, float(sigma_S_per_m)
        self.model, self.psm_model, self.effects, self.noise = model, psm_model, effects, noise
        self.temperature_C = float(temperature_C)
        self.rng = np.random.default_rng(seed)
        self.model_options = model_options
        if simulate is None:
            from electrosense.validation.simulation.models import simulate
        self._simulate = simulate
        n_rec = sensor.n_electrodes - 1
        if effects.channel_gain is not None and len(effects.channel_gain) not in (1, n_rec):
            raise ValueError(f"effect channel_gain: {len(effects.channel_gain)} gains for {n_rec} receivers")

    @property
    def true_tank(self) -> Tank | None:
        """The tank as it really is (tank_size and water_depth effects applied)."""
        e = self.effects
        if self.tank is None:
            if e.tank_size_m is not None or e.water_depth_m is not None:
                raise ValueError("effects tank_size/water_depth need a tank (the meta says unbounded water)")
            return None
        size = e.tank_size_m or self.tank.size_m
        depth = e.water_depth_m if e.water_depth_m is not None else (
            self.tank.water_depth_m if e.tank_size_m is None else None)
        return Tank(tuple(size), depth)

    def describe(self) -> str:
        return (f"{SIMULATOR_LABEL}; model {self.model}; sensor {self.sensor.name} emitter {self.sensor.emitter}; "
                f"noise {self.noise.current_rel:g} relative on currents, {self.noise.position_m:g} m on positions; "
                f"effects: {self.effects.describe()}"
                + (f"; tank mesh grading {self.model_options['tank_grading']:g}"
                   if "tank_grading" in self.model_options else "")
                + (f"; each pose its own tank mesh, the flat faces within {self.model_options['image_faces_within_m']:g}"
                   " m image planes" if "image_faces_within_m" in self.model_options else "")
                + (f"; sensor mesh edge {self.model_options['edge_length_m']:g} m"
                   if "edge_length_m" in self.model_options else ""))

    def _currents_A(self, nominal: np.ndarray, true: np.ndarray, tank, sigma_S_per_m: float, U: np.ndarray):
        """Receiver currents (P, n-1) at the true poses, in the true scene.

        The PSM is evaluated at every true pose. The BEM is evaluated once per
        distinct nominal pose (the passes of a path repeat them) and the
        robot's imprecision, 0.1 mm, is carried by the PSM's relative change
        between the nominal and the true pose (first order in the offset; the
        PSM's own error enters only through that small change). Where the PSM
        cannot represent a pose (a sphere through a wall), the BEM is evaluated
        at every true pose instead.
        """
        e = self.effects
        objects = () if e.unmodelled_object is None else (e.unmodelled_object,)
        scene = dict(objects=objects, contact_impedance_ohm_m2=e.contact_impedance_ohm_m2)

        def per_volt(model, at, **options):   # receiver currents (A) at 1 V
            psm_model = self.psm_model if model == "psm" else None
            return self._simulate(model, self.sensor, at, tank, sigma_S_per_m, psm_model=psm_model, **scene,
                                  **options).receiver_currents_A(1.0)

        if self.model != "bem":
            return per_volt(self.model, true, **self.model_options) * U[:, None]
        distinct, index = np.unique(np.round(nominal, 12), axis=0, return_inverse=True)
        index = index.reshape(-1)
        try:
            psm = per_volt("psm", np.concatenate([true, distinct]))
        except ValueError:  # the PSM cannot represent some pose: the BEM at every true pose
            return per_volt("bem", true, **self.model_options) * U[:, None]
        psm_true, psm_nominal = psm[: len(true)], psm[len(true):][index]
        bem_nominal = per_volt("bem", distinct, **self.model_options)[index]
        return bem_nominal * (psm_true / psm_nominal) * U[:, None]

    def run(self, poses: np.ndarray, rate_hz: float = 10.0, passes: np.ndarray | None = None,
            U_V: float = 1.0) -> SimulatedRun:
        """Simulate every sample of a trajectory (all poses in one batched model call)."""
        poses = np.asarray(poses, dtype=float).reshape(-1, 4)
        P = len(poses)
        if rate_hz <= 0:
            raise ValueError(f"rate must be positive, got {rate_hz} Hz")
        e = self.effects
        t = np.arange(P) / float(rate_hz)
        true = poses.copy()
        if e.pose_offset is not None:
            true += np.asarray(e.pose_offset)
        true[:, :3] += self.rng.normal(0.0, self.noise.position_m, size=(P, 3))
        tank = self.true_tank
        if tank is not None:
            inside = tank.contains(true[:, :3])
            if not inside.all():
                raise ValueError(f"pose {int(np.flatnonzero(~inside)[0])} of the trajectory is out of the water")
        sigma0 = self.sigma_S_per_m * (1.0 + e.conductivity_rel)
        U = np.full(P, float(U_V))
        currents = self._currents_A(poses if e.pose_offset is None else poses + np.asarray(e.pose_offset), true,
                                    tank, sigma0, U)
        # temperature drift: the conductivity follows the temperature (K is proportional to sigma;
        # with a contact impedance this neglects the second-order change of sigma * z_c)
        duration = t[-1] if P > 1 else 1.0
        temp = self.temperature_C + e.temperature_drift_K * t / max(duration, 1e-12)
        scale = 1.0 + TEMPERATURE_COEFFICIENT_PER_K * (temp - self.temperature_C)
        currents = currents * scale[:, None]
        if e.channel_gain is not None:
            currents = currents * np.asarray(e.channel_gain)[None, :]
        currents = currents * (1.0 + self.rng.normal(0.0, self.noise.current_rel, size=currents.shape))
        return SimulatedRun(
            t_s=t, poses=poses, true_poses=true, U_V=U, currents_A=currents, temp_C=temp,
            sigma_true_S_per_m=sigma0 * scale, passes=np.zeros(P, dtype=np.int64) if passes is None else
            np.asarray(passes, dtype=np.int64), sensor=self.sensor,
            info={"model": self.model, "effects": e.describe(), "description": self.describe()},
        )
