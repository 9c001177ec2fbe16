"""A tank map: the BEM's K over every pose a robot can reach at one depth, interpolated, with its own error.

The PSM is fast but a percent off the BEM in a tank it was not calibrated
for, most of it near the walls, where a robot needs it most. A map is built
once per sensor, tank (and fixed objects) and depth:

1. the candidate poses: (x, y, heading) on a grid at depth ``z_m`` with the
   sensor's surface at least ``wall_gap_m`` from every wall, floor and
   surface (:func:`reachable_poses`);
2. the BEM (:class:`electrosense.bem.PoseSweep`, one tank mesh graded towards
   the whole plane) at a first spread of them (farthest-point sampling in the
   sensor's tip positions), then, round after round, at the candidates of
   largest estimated error, until the largest is below ``target`` (a third of
   the bench noise by default) or the time is spent;
3. log(K_bem / K_free) of every electrode pair interpolated over the tip
   positions (:class:`~electrosense.validation.diagnosis.anchored.RBFInterpolant`,
   cubic with a linear trend), its leave-one-out error at every node, and
   the error estimated at every candidate from its nearest nodes
   (:func:`~electrosense.validation.diagnosis.anchored.estimated_error`).

The map is one ``.npz`` file: the nodes, the BEM's K there, the scene, the
sensor, the BEM options and the code version inside; loading it refits the
interpolant (milliseconds for a few hundred nodes). A killed build resumes
from the nodes it saved after each round.

Example
-------
>>> from electrosense.meshes import preset
>>> from electrosense.meshes.tank import Tank
>>> P = reachable_poses(preset("angels-4"), Tank((1.0, 1.0, 1.0)), 0.0, spacing_m=0.1, n_headings=4)
>>> P.shape[1], bool(abs(P[:, 0]).max() < 0.5)
(4, True)
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["TankMap", "MapEvaluator", "reachable_poses", "sensor_wall_gap_m", "build_tank_map", "load_tank_map"]


def sensor_wall_gap_m(sensor, tank, poses: np.ndarray, n_axis: int = 9) -> np.ndarray:
    """(P,) the smallest distance (m) from the sensor's surface (a cylinder of its radius with round ends) to
    the tank's walls, floor and free surface."""
    from electrosense.meshes.pose import sensor_to_tank

    half = 0.5 * sensor.length_m - sensor.radius_m
    axis = np.c_[np.linspace(-half, half, n_axis), np.zeros(n_axis), np.zeros(n_axis)]
    pts = sensor_to_tank(axis, np.asarray(poses, float))  # (P, n_axis, 3)
    return tank.distance_to_boundary_m(pts).min(axis=(1, 2)) - sensor.radius_m


def reachable_poses(sensor, tank, z_m: float, wall_gap_m: float = 0.005, spacing_m: float = 0.01,
                    n_headings: int = 48) -> np.ndarray:
    """(C, 4) poses (x, y, z_m, yaw) on a grid of ``spacing_m`` and ``n_headings`` headings over the full turn,
    with the sensor's surface at least ``wall_gap_m`` from every boundary."""
    lo, hi = tank.water_bounds_m
    xs = np.arange(lo[0] + wall_gap_m, hi[0] - wall_gap_m + 1e-12, spacing_m)
    ys = np.arange(lo[1] + wall_gap_m, hi[1] - wall_gap_m + 1e-12, spacing_m)
    yaws = np.linspace(0.0, 2 * np.pi, n_headings, endpoint=False)
    X, Y, W = np.meshgrid(xs, ys, yaws, indexing="ij")
    P = np.c_[X.ravel(), Y.ravel(), np.full(X.size, z_m), W.ravel()]
    return P[sensor_wall_gap_m(sensor, tank, P) >= wall_gap_m]


def _farthest_points(F: np.ndarray, k: int, start: np.ndarray | None = None) -> np.ndarray:
    """Indices of ``k`` rows of ``F`` spread by farthest-point sampling (from the rows ``start`` if given)."""
    d = np.full(len(F), np.inf)
    for s in (start if start is not None else F[:0]):
        d = np.minimum(d, np.linalg.norm(F - s, axis=1))
    out = []
    i = int(np.argmax(d)) if np.isfinite(d).any() else 0
    for _ in range(min(k, len(F))):
        out.append(i)
        d = np.minimum(d, np.linalg.norm(F - F[i], axis=1))
        i = int(np.argmax(d))
    return np.asarray(out, int)


@dataclass
class TankMap:
    """The BEM's conductance over pose in one scene at unit conductivity, interpolated (module doc)."""

    sensor: object
    tank: object
    z_m: float
    nodes: np.ndarray  # (B, 4) poses where the BEM was solved
    K_nodes: np.ndarray  # (B, n, n) the BEM there, 1 S/m
    K_free: np.ndarray  # (n, n) unbounded water, 1 S/m
    objects: tuple = ()
    bem_options: dict = field(default_factory=dict)
    code: str = ""
    wall_gap_m: float = 0.005
    history: list = field(default_factory=list)
    sigma_S_per_m: float | None = None  # the water's conductivity the map was built for (K is kept at 1 S/m)

    def __post_init__(self):
        from electrosense.validation.diagnosis.anchored import RBFInterpolant, pose_features

        n = self.K_free.shape[0]
        self._iu = np.triu_indices(n, 1)
        self._F = pose_features(self.sensor, self.nodes)
        L = np.log(self.K_nodes[:, self._iu[0], self._iu[1]] / self.K_free[self._iu])
        self._interp = RBFInterpolant(self._F, L)
        e = self.sensor.emitter - 1
        self._rec = [self._iu_index(min(k, e), max(k, e)) for k in range(n) if k != e]

    def _iu_index(self, i, j) -> int:
        return int(np.flatnonzero((self._iu[0] == i) & (self._iu[1] == j))[0])

    @property
    def leave_one_out(self) -> np.ndarray:
        """(B, m) relative leave-one-out error of the receiver currents at the nodes (approximately)."""
        return np.abs(np.expm1(self._interp.leave_one_out[:, self._rec]))

    def conductance(self, poses, sigma_S_per_m: float = 1.0) -> np.ndarray:
        """K (P, n, n) at ``poses`` (P, 4), zero row sums, at ``sigma_S_per_m``."""
        from electrosense.validation.diagnosis.anchored import pose_features

        poses = np.asarray(poses, float).reshape(-1, 4)
        L = self._interp(pose_features(self.sensor, poses))
        n = self.K_free.shape[0]
        K = np.zeros((len(poses), n, n))
        K[:, self._iu[0], self._iu[1]] = self.K_free[self._iu] * np.exp(L)
        K = K + K.transpose(0, 2, 1)
        K[:, np.arange(n), np.arange(n)] = -K.sum(axis=-1)
        return K * sigma_S_per_m

    def jacobian(self, poses, sigma_S_per_m: float = 1.0, step=(1e-4, 1e-4, 1e-3)) -> np.ndarray:
        """dK / d(x, y, yaw) (P, 3, n, n) by central differences of the interpolant (steps in m, m, rad)."""
        poses = np.asarray(poses, float).reshape(-1, 4)
        out = []
        for axis, h in zip((0, 1, 3), step):
            d = np.zeros(4)
            d[axis] = h
            out.append((self.conductance(poses + d, sigma_S_per_m) - self.conductance(poses - d, sigma_S_per_m))
                       / (2 * h))
        return np.stack(out, axis=1)

    def estimated_error(self, poses) -> np.ndarray:
        """(P, m) estimated relative error of the receiver currents at ``poses`` (zero at the nodes)."""
        from electrosense.validation.diagnosis.anchored import estimated_error, pose_features

        return estimated_error(self._F, self.leave_one_out, pose_features(self.sensor, np.asarray(poses, float)))

    # ------------------------------------------------------------------ file
    def save(self, path) -> Path:
        """One ``.npz``: arrays, and the scene, sensor, options and code version as JSON."""
        path = Path(path)
        meta = {"format": "electrosense tank map 1", "sensor": self.sensor.to_dict(),
                "tank": {"size_m": list(self.tank.size_m), "water_depth_m": self.tank.water_depth_m},
                "objects": repr(self.objects), "z_m": self.z_m, "wall_gap_m": self.wall_gap_m,
                "bem_options": {k: v for k, v in self.bem_options.items() if isinstance(v, (int, float, str))},
                "code": self.code, "history": self.history, "sigma_S_per_m": self.sigma_S_per_m}
        partial = path.with_name(path.name + ".writing.npz")
        np.savez(partial, nodes=self.nodes, K_nodes=self.K_nodes, K_free=self.K_free, meta=json.dumps(meta))
        partial.replace(path)
        return path


def load_tank_map(path) -> TankMap:
    """A :class:`TankMap` from its file (refuses another format, and objects, which are not stored yet)."""
    from electrosense.meshes.sensor import SensorDescription
    from electrosense.meshes.tank import Tank

    path = Path(path)
    try:
        with np.load(path) as z:
            meta = json.loads(str(z["meta"]))
            nodes, K_nodes, K_free = z["nodes"], z["K_nodes"], z["K_free"]
    except (OSError, KeyError, ValueError) as exc:
        raise ValueError(f"{path}: not a tank map ({exc})") from None
    if meta.get("format") != "electrosense tank map 1":
        raise ValueError(f"{path}: not a tank map (format {meta.get('format')!r})")
    if meta.get("objects") not in ("()", None):
        raise ValueError(f"{path}: a map with objects cannot be loaded yet")
    tank = Tank(tuple(meta["tank"]["size_m"]), meta["tank"]["water_depth_m"])
    return TankMap(SensorDescription.from_dict(meta["sensor"]), tank, float(meta["z_m"]), nodes, K_nodes, K_free,
                   (), meta.get("bem_options", {}), meta.get("code", ""), float(meta.get("wall_gap_m", 0.005)),
                   meta.get("history", []), meta.get("sigma_S_per_m"))


def build_tank_map(sensor, tank, z_m: float, path=None, target: float = 1.7e-4, wall_gap_m: float = 0.005,
                   spacing_m: float = 0.01, n_headings: int = 48, first: int = 60, per_round: int = 30,
                   max_seconds: float = 240.0, bem_options: dict | None = None, sigma_S_per_m: float | None = None,
                   progress=None) -> TankMap:
    """Build (or resume, from ``path``) the map of ``sensor`` in ``tank`` at depth ``z_m`` (module doc).

    ``target``: the largest estimated relative error of a receiver current over the candidates at which the
    build stops; ``max_seconds``: wall-clock budget of the BEM (the map is then saved as it stands, its
    estimated error with it).
    """
    from electrosense.bem import PoseSweep
    from electrosense.meshes.scene_mesh import trajectory_focus_m
    from electrosense.validation.diagnosis.anchored import default_bem_options, pose_features
    from electrosense.validation.simulation.models import code_version, free_space_bem

    say = progress or (lambda s: None)
    t0 = time.perf_counter()
    options = default_bem_options(sensor, bem_options)
    code = code_version()
    C = reachable_poses(sensor, tank, z_m, wall_gap_m, spacing_m, n_headings)
    if not len(C):
        raise ValueError(f"no pose at depth z = {z_m} m keeps the sensor {wall_gap_m} m from the walls")
    F = pose_features(sensor, C)
    say(f"{len(C)} candidate poses (grid {spacing_m} m, {n_headings} headings, {wall_gap_m * 1e3:g} mm from "
        "the walls)")
    K_free = free_space_bem(sensor, options.get("edge_length_m")).K_S
    nodes, K_nodes, history = np.zeros((0, 4)), np.zeros((0,) + K_free.shape), []
    if path is not None and Path(path).exists():
        old = load_tank_map(path)
        same = (old.sensor.to_dict() == sensor.to_dict() and old.tank == tank and abs(old.z_m - z_m) < 1e-9
                and old.code == code)
        if same:
            nodes, K_nodes, history = old.nodes, old.K_nodes, list(old.history)
            say(f"resuming from {len(nodes)} BEM poses in {path}")
    sweep = PoseSweep(sensor, tank, (), sigma_S_per_m=1.0,
                      focus_m=trajectory_focus_m(sensor, C[_farthest_points(F, 400)]), **options)
    say(f"tank mesh ready ({time.perf_counter() - t0:.0f} s)")

    def solve(idx):
        nonlocal nodes, K_nodes
        K = sweep.conductance(C[idx]).K_S
        nodes, K_nodes = np.vstack([nodes, C[idx]]), np.vstack([K_nodes, K])

    if len(nodes) < first:
        solve(_farthest_points(F, first - len(nodes), pose_features(sensor, nodes) if len(nodes) else None))
    while True:
        m = TankMap(sensor, tank, z_m, nodes, K_nodes, K_free, (), options, code, wall_gap_m, history, sigma_S_per_m)
        err = m.estimated_error(C).max(axis=1)
        round_ = {"bem_poses": len(nodes), "max_error": float(err.max()), "rms_error": float(np.sqrt(np.mean(err**2))),
                  "seconds": time.perf_counter() - t0}
        history.append(round_)
        m.history = history
        if path is not None:
            m.save(path)
        say(f"{len(nodes)} BEM poses: estimated error max {100 * err.max():.4f} %, RMS "
            f"{100 * round_['rms_error']:.4f} % (target {100 * target:.4f} %)")
        if err.max() <= target:
            break
        if time.perf_counter() - t0 > max_seconds:
            say(f"time budget of {max_seconds:.0f} s spent: the map is saved with its estimated error")
            break
        worst = np.argsort(err)[::-1][: 20 * per_round]
        pick = worst[_farthest_points(F[worst], per_round, m._F)]
        solve(pick)
    return m


@dataclass
class MapEvaluator:
    """A :class:`TankMap` as a model of :func:`~electrosense.validation.simulation.models.pose_evaluator`:
    ``.conductance(poses) -> ConductanceMatrix`` at ``sigma_S_per_m``; refuses poses off the map's depth or
    closer to a wall than it was built for (an interpolant does not extrapolate)."""

    tank_map: TankMap
    sigma_S_per_m: float

    def conductance(self, poses, progress: bool = False):
        from electrosense.bem.conductance import ConductanceMatrix

        poses = np.asarray(poses, float).reshape(-1, 4)
        m = self.tank_map
        off = np.abs(poses[:, 2] - m.z_m) > 1e-6
        if off.any():
            raise ValueError(f"the map is at z = {m.z_m} m; pose {int(np.argmax(off))} is at z = "
                             f"{poses[np.argmax(off), 2]} m")
        gap = sensor_wall_gap_m(m.sensor, m.tank, poses)
        if (gap < m.wall_gap_m - 1e-9).any():
            i = int(np.argmin(gap))
            raise ValueError(f"pose {i} puts the sensor {1e3 * gap[i]:.1f} mm from a wall; the map reaches "
                             f"{1e3 * m.wall_gap_m:g} mm")
        return ConductanceMatrix(m.conductance(poses, self.sigma_S_per_m), m.sensor.emitter, self.sigma_S_per_m,
                                 {"model": "map", "bem_poses": int(len(m.nodes))})
