"""What the diagnosis knows about a run: the logged poses, currents, times, passes and the meta line.

:class:`Observations` is a plain container built from one or several bench
logs (:func:`from_bench_logs`) or directly from arrays (tests, studies). The
diagnosis is told nothing else: the sensor, the tank, the nominal conductivity
and the temperature come from the meta line and the columns.

Example
-------
>>> import numpy as np
>>> from electrosense.meshes.sensor import preset
>>> from electrosense.meshes.tank import Tank
>>> obs = Observations(poses=np.zeros((8, 4)), currents_A=np.ones((8, 3)), sensor=preset("angels-4"),
...                    tank=Tank((1, 1, 1)), sigma_S_per_m=0.0354)
>>> obs.n_poses, obs.n_receivers, obs.passes.tolist()
(8, 3, [0, 0, 0, 0, 0, 0, 0, 0])
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from electrosense.meshes.sensor import SensorDescription
from electrosense.meshes.tank import Tank
from electrosense.validation.bench.log.header import logged_objects

__all__ = ["Observations", "DiagnosisInputError", "from_bench_logs"]


class DiagnosisInputError(ValueError):
    """Observations the diagnosis cannot work with, with the reason."""


@dataclass
class Observations:
    """Logged data of one run (one or several passes).

    Parameters
    ----------
    poses : (P, 4) array
        Logged poses (x_m, y_m, z_m, yaw_rad), tank frame.
    currents_A : (P, m) array
        Receiver currents, positive into the receivers.
    sensor : SensorDescription
        With the emitter of the meta line.
    tank : Tank or None
        The tank as believed (meta line); ``None`` for unbounded water.
    sigma_S_per_m : float
        Conductivity as believed (meta line).
    U_V : (P,) array, optional
        Emitter voltage (default 1 V).
    t_s : (P,) array, optional
        Time (default: the sample index, in seconds).
    passes : (P,) int array, optional
        Pass number of each sample (default: one pass).
    temperature_C : (P,) array, optional
        Logged water temperature.
    meta : dict
        The meta line, kept as read.
    objects : tuple
        Objects known to be in the tank.
    sigma_logged_S_per_m : (P,) array, optional
        Conductimeter readings logged with the samples (reported, not used).
    """

    poses: np.ndarray
    currents_A: np.ndarray
    sensor: SensorDescription
    tank: Tank | None
    sigma_S_per_m: float
    U_V: np.ndarray | None = None
    t_s: np.ndarray | None = None
    passes: np.ndarray | None = None
    temperature_C: np.ndarray | None = None
    meta: dict = field(default_factory=dict)
    objects: tuple = ()
    source: str = ""
    sigma_logged_S_per_m: np.ndarray | None = None
    #: the fewest samples the use needs (a diagnosis's held-out halves and BIC: 8; a track with the noise measured
    #: on the log: 3, its second differences; with the noise given: 1), and what for, said where there are fewer
    min_samples: int = 8
    min_samples_for: str = "to diagnose"

    def __post_init__(self):
        self.poses = np.asarray(self.poses, dtype=float).reshape(-1, 4)
        P = len(self.poses)
        self.currents_A = np.asarray(self.currents_A, dtype=float).reshape(P, -1)
        m = self.sensor.n_electrodes - 1
        if self.currents_A.shape[1] != m:
            raise DiagnosisInputError(
                f"{self.source or 'observations'}: {self.currents_A.shape[1]} current columns for a sensor with {m} receivers"
            )
        self.U_V = np.ones(P) if self.U_V is None else np.broadcast_to(np.asarray(self.U_V, float), (P,)).copy()
        self.t_s = np.arange(P, dtype=float) if self.t_s is None else np.asarray(self.t_s, float).reshape(P)
        self.passes = np.zeros(P, int) if self.passes is None else np.asarray(self.passes).reshape(P).astype(int)
        if self.temperature_C is not None:
            self.temperature_C = np.asarray(self.temperature_C, float).reshape(P)
        for name in ("poses", "currents_A", "U_V", "t_s"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise DiagnosisInputError(f"{self.source or 'observations'}: {name} has non-finite values")
        if P < self.min_samples:
            raise DiagnosisInputError(f"{self.source or 'observations'}: {P} samples are too few (need >= "
                                      f"{self.min_samples} {self.min_samples_for})")
        if np.any(self.U_V == 0):
            raise DiagnosisInputError(f"{self.source or 'observations'}: U_V is zero on some rows")

    @property
    def n_poses(self) -> int:
        return len(self.poses)

    @property
    def n_receivers(self) -> int:
        return self.currents_A.shape[1]

    @property
    def emitter(self) -> int:
        return self.sensor.emitter

    def pass_indices(self) -> list[np.ndarray]:
        """Sample indices of each pass, in time order."""
        out = []
        for p in np.unique(self.passes):
            idx = np.flatnonzero(self.passes == p)
            out.append(idx[np.argsort(self.t_s[idx], kind="stable")])
        return out

    @property
    def has_temperature(self) -> bool:
        return self.temperature_C is not None and float(np.ptp(self.temperature_C)) > 0.0


def _one(log, pass_offset: int) -> dict:
    data = getattr(log, "data", None)
    temp, sig = None, None
    if data is not None and "sigma_S_per_m" in getattr(data, "columns", ()):
        sig = np.asarray(data["sigma_S_per_m"], dtype=float)
    if data is not None and "temp_C" in getattr(data, "columns", ()):
        temp = np.asarray(data["temp_C"], dtype=float)
        if not np.all(np.isfinite(temp)):
            temp = None
    passes = getattr(log, "passes", None)
    P = len(log.poses)
    passes = np.zeros(P, int) if passes is None else np.asarray(passes).astype(int)
    # renumber passes 0..k-1 within this log, then offset
    _, passes = np.unique(passes, return_inverse=True)
    return dict(
        poses=np.asarray(log.poses, float), currents=np.asarray(log.currents_A, float), U=np.asarray(log.U_V, float),
        t=np.asarray(log.t_s, float), passes=passes.reshape(-1) + pass_offset, temp=temp, sigma=sig,
    )


def from_bench_logs(logs, min_samples: int = 8, min_samples_for: str = "to diagnose") -> Observations:
    """Observations from one or more :class:`electrosense.validation.bench.log.BenchLog` of the same run set-up
    (at least ``min_samples`` samples, ``min_samples_for`` what, :attr:`Observations.min_samples`).

    Each log's passes keep their own numbers (offset so that logs never share
    one); times of later logs are shifted to follow the earlier ones, so that a
    drift in time stays a drift. Logs that disagree on the sensor, tank or
    nominal conductivity are refused.
    """
    logs = list(logs)
    if not logs:
        raise DiagnosisInputError("no bench log given")
    first = logs[0]
    parts, offset, t_end = [], 0, 0.0
    for log in logs:
        for attr in ("tank", "sigma_S_per_m"):
            if getattr(log, attr) != getattr(first, attr):
                raise DiagnosisInputError(
                    f"bench logs disagree on {attr}: {getattr(first, attr)!r} vs {getattr(log, attr)!r}"
                )
        if log.sensor.to_dict() != first.sensor.to_dict():
            raise DiagnosisInputError("bench logs were taken with different sensors or emitters")
        part = _one(log, offset)
        if parts:
            part["t"] = part["t"] - part["t"].min() + t_end + 1.0
        t_end = float(part["t"].max())
        offset = int(part["passes"].max()) + 1
        parts.append(part)
    temps = [p["temp"] for p in parts]
    temperature = np.concatenate(temps) if all(t is not None for t in temps) else None
    sigmas = [p["sigma"] for p in parts]
    sigma_logged = np.concatenate(sigmas) if all(s is not None for s in sigmas) else None
    meta = dict(getattr(first, "meta", {}) or {})
    objects = [logged_objects(getattr(log, "meta", {}) or {}, getattr(log, "path", "") or "") for log in logs]
    if any(o != objects[0] for o in objects):
        raise DiagnosisInputError("bench logs disagree on the objects in the tank (meta 'objects')")
    return Observations(
        poses=np.concatenate([p["poses"] for p in parts]),
        currents_A=np.concatenate([p["currents"] for p in parts]),
        sensor=first.sensor,
        tank=first.tank,
        sigma_S_per_m=float(first.sigma_S_per_m),
        U_V=np.concatenate([p["U"] for p in parts]),
        t_s=np.concatenate([p["t"] for p in parts]),
        passes=np.concatenate([p["passes"] for p in parts]),
        temperature_C=temperature,
        meta=meta,
        source=", ".join(str(getattr(log, "path", "") or "") for log in logs),
        sigma_logged_S_per_m=sigma_logged,
        objects=objects[0],
        min_samples=min_samples,
        min_samples_for=min_samples_for,
    )
