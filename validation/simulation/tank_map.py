"""A tank map: the BEM's K over every pose a robot can reach at one depth (or a band), interpolated, with its error.

The PSM is fast but a percent off the BEM in a tank it was not calibrated
for, most of it near the walls, where a robot needs it most. A map is built
once per sensor, tank (box or cylinder, with its fixed objects) and depth:

1. the candidate poses: (x, y, heading) on a grid at depth ``z_m`` (or
   several depths of a band) with the sensor's surface at least
   ``wall_gap_m`` from every wall, floor, surface and object
   (:func:`reachable_poses`), folded into the tank's fundamental domain
   (:mod:`.map_coordinates`);
2. the BEM (:class:`electrosense.bem.PoseSweep`, one tank mesh graded towards
   the whole plane, on ``workers`` processes) at a first spread of them
   (farthest-point sampling in the map's warped coordinates, which crowds
   them near the walls), then, round after round, at the candidates of
   largest estimated error, until that is below the target (a third of the
   bench noise, RMS and max) or the time is spent;
3. log(K_bem / K_free) of every electrode pair interpolated over the
   warped coordinates (cubic radial basis functions with a linear trend,
   :class:`~electrosense.validation.diagnosis.anchored.RBFInterpolant`), its
   leave-one-out error at every node, and the error estimated anywhere from
   the nearest nodes' (:func:`~electrosense.validation.diagnosis.anchored.estimated_error`).

The map is one ``.npz`` file: the nodes, the BEM's K there, the interpolant's
coefficients, the scene, the sensor, the BEM options and the code version;
loading it reads arrays (milliseconds). A killed build resumes from the nodes
saved after each round. :meth:`TankMap.conductance` evaluates K and its pose
Jacobian for many poses in one vectorised call.

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
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from electrosense.validation.simulation.map_coordinates import DEFAULT_WARP_M, MapFrame

__all__ = ["TankMap", "MapEvaluator", "reachable_poses", "sensor_wall_gap_m", "build_tank_map", "load_tank_map",
           "MAP_FORMAT", "scene_record", "scene_from_record", "same_scene"]

MAP_FORMAT = "electrosense tank map 2"

#: relative error targets of the receiver currents: a third of the bench noise (RMS) and 0.05 % at most
TARGET_RMS = 1.7e-4
TARGET_MAX = 5e-4


# ------------------------------------------------------------------ poses
def _axis_points(sensor, poses, n_axis: int = 9) -> np.ndarray:
    from electrosense.meshes.pose import sensor_to_tank

    half = 0.5 * sensor.length_m - sensor.radius_m
    axis = np.c_[np.linspace(-half, half, n_axis), np.zeros(n_axis), np.zeros(n_axis)]
    return sensor_to_tank(axis, np.asarray(poses, float).reshape(-1, 4))  # (P, n_axis, 3)


def sensor_wall_gap_m(sensor, tank, poses: np.ndarray, objects=()) -> np.ndarray:
    """(P,) the smallest distance (m) from the sensor's surface (a cylinder of its radius with round ends) to the
    tank's walls, floor and free surface, and to the fixed ``objects``."""
    from electrosense.meshes.scene_mesh import distance_to_object_m

    pts = _axis_points(sensor, poses)
    gap = tank.distance_to_boundary_m(pts).min(axis=(1, 2))
    for obj in objects:
        gap = np.minimum(gap, distance_to_object_m(obj, pts).min(axis=1))
    return gap - sensor.radius_m


def reachable_poses(sensor, tank, z_m, wall_gap_m: float = 0.005, spacing_m: float = 0.01, n_headings: int = 48,
                    objects=()) -> np.ndarray:
    """(C, 4) poses (x, y, z, yaw) on a grid of ``spacing_m``, ``n_headings`` headings over the full turn and the
    depths ``z_m`` (one or several), with the sensor's surface at least ``wall_gap_m`` from every boundary."""
    lo, hi = tank.water_bounds_m
    xs = np.arange(lo[0] + wall_gap_m, hi[0] - wall_gap_m + 1e-12, spacing_m)
    ys = np.arange(lo[1] + wall_gap_m, hi[1] - wall_gap_m + 1e-12, spacing_m)
    yaws = np.linspace(0.0, 2 * np.pi, n_headings, endpoint=False)
    zs = np.atleast_1d(np.asarray(z_m, float))
    X, Y, Z, W = np.meshgrid(xs, ys, zs, yaws, indexing="ij")
    P = np.c_[X.ravel(), Y.ravel(), Z.ravel(), W.ravel()]
    return P[sensor_wall_gap_m(sensor, tank, P, objects) >= wall_gap_m]


def _farthest_points(F: np.ndarray, k: int, start: np.ndarray | None = None) -> np.ndarray:
    """Indices of ``k`` rows of ``F`` spread by farthest-point sampling (from the rows ``start`` if given)."""
    d = np.full(len(F), np.inf)
    if start is not None and len(start):
        from scipy.spatial import cKDTree

        d = cKDTree(start).query(F)[0]
    out = []
    i = int(np.argmax(d)) if np.isfinite(d).any() else 0
    for _ in range(min(k, len(F))):
        out.append(i)
        d = np.minimum(d, np.linalg.norm(F - F[i], axis=1))
        i = int(np.argmax(d))
    return np.asarray(out, int)


# ------------------------------------------------------------------ scene in the file
def scene_record(tank, objects=()) -> dict:
    """The tank and fixed objects as plain JSON data (:func:`scene_from_record` reads them back)."""
    from dataclasses import asdict

    if hasattr(tank, "radius_m"):
        t = {"kind": "cylinder", "radius_m": tank.radius_m, "height_m": tank.height_m,
             "water_depth_m": tank.water_depth_m, "floor_radius_m": tank.floor_radius_m}
    else:
        t = {"kind": "box", "size_m": list(tank.size_m), "water_depth_m": tank.water_depth_m}
    objs = []
    for o in objects:
        d = {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(o).items()}
        d["conductivity_S_per_m"] = repr(float(o.conductivity_S_per_m))   # inf survives JSON as text
        objs.append({"shape": type(o).__name__.lower(), **d})
    return {"tank": t, "objects": objs}


def same_scene(tank, objects, other_tank, other_objects, tol_m: float = 1e-5) -> bool:
    """Whether two scenes are one, lengths compared to ``tol_m`` (a log's meta line keeps six digits).

    >>> from electrosense.meshes.tank import Tank
    >>> same_scene(Tank((0.6686797, 0.4, 0.3)), (), Tank((0.66868, 0.4, 0.3)), ())
    True
    """
    if tank is None or other_tank is None:
        return tank is other_tank
    return _close(scene_record(tank, objects), scene_record(other_tank, other_objects), tol_m)


def _close(a, b, tol: float) -> bool:
    """Equal records, numbers to ``tol``."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k], tol) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_close(u, v, tol) for u, v in zip(a, b))
    numbers = (int, float)
    if isinstance(a, numbers) and isinstance(b, numbers) and not isinstance(a, bool) and not isinstance(b, bool):
        return abs(a - b) <= tol
    return a == b


def scene_from_record(record: dict):
    """(tank, objects) from :func:`scene_record`'s data."""
    from electrosense.meshes.cylinder_tank import CylinderTank
    from electrosense.meshes.objects import Box, Cylinder, Sphere
    from electrosense.meshes.tank import Tank

    t = dict(record["tank"])
    kind = t.pop("kind")
    tank = CylinderTank(**t) if kind == "cylinder" else Tank(tuple(t["size_m"]), t["water_depth_m"])
    shapes = {"sphere": Sphere, "box": Box, "cylinder": Cylinder}
    objects = []
    for o in record.get("objects", []):
        o = dict(o)
        cls = shapes[o.pop("shape")]
        o["conductivity_S_per_m"] = float(o["conductivity_S_per_m"])
        objects.append(cls(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in o.items()}))
    return tank, tuple(objects)


# ------------------------------------------------------------------ the map
@dataclass
class TankMap:
    """The BEM's conductance over pose in one scene at unit conductivity, interpolated (module doc).

    ``z_m``: the depth (m) of the map, or ``(z_min, z_max)`` for a band.
    """

    sensor: object
    tank: object
    z_m: object
    nodes: np.ndarray  # (B, 4) poses where the BEM was solved
    K_nodes: np.ndarray  # (B, n, n) the BEM there, 1 S/m
    K_free: np.ndarray  # (n, n) unbounded water, 1 S/m
    objects: tuple = ()
    bem_options: dict = field(default_factory=dict)
    code: str = ""
    wall_gap_m: float = 0.005
    history: list = field(default_factory=list)
    sigma_S_per_m: float | None = None  # the water's conductivity the map was built for (K is kept at 1 S/m)
    warp_m: float = DEFAULT_WARP_M
    fitted: dict | None = None  # {"X", "coef", "loo"}: the interpolant, as stored (else fitted from the nodes)

    def __post_init__(self):
        n = self.K_free.shape[0]
        self.objects = tuple(self.objects)
        self._iu = np.triu_indices(n, 1)
        e = self.sensor.emitter - 1
        pairs = list(zip(*self._iu))
        self._rec = [pairs.index((min(k, e), max(k, e))) for k in range(n) if k != e]
        self.frame = MapFrame(self.sensor, self.tank, self.objects, self.band, self.warp_m)
        if self.fitted is None:
            from electrosense.validation.diagnosis.anchored import RBFInterpolant

            X = self.frame.features(self.nodes)
            L = np.log(self.K_nodes[:, self._iu[0], self._iu[1]] / self.K_free[self._iu])
            interp = RBFInterpolant(X, L)
            self.fitted = {"X": X, "coef": interp.coef, "loo": interp.leave_one_out}
        self._X = np.asarray(self.fitted["X"], float)
        self._coef = np.asarray(self.fitted["coef"], float)
        self._X2 = np.sum(self._X**2, axis=1)
        self._linear = len(self._coef) > len(self._X) + 1

    @property
    def band(self) -> bool:
        return np.ndim(self.z_m) > 0

    @property
    def z_range_m(self) -> tuple[float, float]:
        z = np.atleast_1d(np.asarray(self.z_m, float))
        return float(z.min()), float(z.max())

    @property
    def leave_one_out(self) -> np.ndarray:
        """(B, m) relative leave-one-out error of the receiver currents at the nodes."""
        return np.abs(np.expm1(np.asarray(self.fitted["loo"])[:, self._rec]))

    def log_ratio(self, poses, jacobian: bool = False, chunk: int = 4096):
        """log(K / K_free) of the upper triangle, (P, pairs); with ``jacobian`` also its d/d(x, y, yaw), (P, 3, pairs)."""
        poses = np.asarray(poses, float).reshape(-1, 4)
        B = len(self._X)
        out, dout = [], []
        for s in range(0, len(poses), chunk):
            F, dF = self.frame.features(poses[s:s + chunk], jacobian=True) if jacobian else \
                (self.frame.features(poses[s:s + chunk]), None)
            r = np.sqrt(np.maximum(np.sum(F**2, axis=1)[:, None] + self._X2[None, :] - 2.0 * F @ self._X.T, 0.0))
            c, t = self._coef[:B], self._coef[B:]
            L = (r**3) @ c + t[0]
            if self._linear:
                L = L + F @ t[1:]
            out.append(L)
            if jacobian:
                # d/dF_k sum_b r_b^3 c_b = 3 sum_b r_b (F_k - X_bk) c_b
                rc = r @ c  # (p, pairs)
                G = 3.0 * (F[:, :, None] * rc[:, None, :] - np.stack([r @ (self._X[:, k, None] * c)
                                                                       for k in range(F.shape[1])], axis=1))
                if self._linear:
                    G = G + t[1:][None]
                dout.append(np.einsum("pkq,pkj->pjq", G, dF))
        L = np.concatenate(out) if out else np.zeros((0, len(self._iu[0])))
        return (L, np.concatenate(dout)) if jacobian else L

    def conductance(self, poses, sigma_S_per_m: float = 1.0, jacobian: bool = False):
        """K (P, n, n) at ``poses`` (P, 4), zero row sums, at ``sigma_S_per_m``; with ``jacobian`` also
        dK / d(x, y, yaw), (P, 3, n, n): one vectorised call for any number of poses."""
        n = self.K_free.shape[0]
        iu = self._iu
        res = self.log_ratio(poses, jacobian)
        L, dL = res if jacobian else (res, None)
        off = self.K_free[iu] * np.exp(L) * sigma_S_per_m
        K = _assemble(off, n, iu)
        if not jacobian:
            return K
        return K, _assemble(off[:, None, :] * dL, n, iu)

    def jacobian(self, poses, sigma_S_per_m: float = 1.0) -> np.ndarray:
        """dK / d(x, y, yaw) (P, 3, n, n) (analytic: the interpolant's derivative through the map's coordinates)."""
        return self.conductance(poses, sigma_S_per_m, jacobian=True)[1]

    def estimated_error(self, poses) -> np.ndarray:
        """(P, m) estimated relative error of the receiver currents at ``poses`` (zero at the nodes)."""
        from electrosense.validation.diagnosis.anchored import estimated_error

        return estimated_error(self._X, self.leave_one_out, self.frame.features(np.asarray(poses, float)))

    def covers(self, poses) -> tuple[np.ndarray, str]:
        """(P,) bool: poses inside the map (its depth or band, its wall gap), and why the first other is not."""
        poses = np.asarray(poses, float).reshape(-1, 4)
        z0, z1 = self.z_range_m
        off_z = (poses[:, 2] < z0 - 1e-6) | (poses[:, 2] > z1 + 1e-6)
        gap = sensor_wall_gap_m(self.sensor, self.tank, poses, self.objects)
        close = gap < self.wall_gap_m - 1e-6
        why = ""
        if off_z.any():
            i = int(np.argmax(off_z))
            where = f"z = {z0:g} m" if z1 == z0 else f"z = {z0:g} to {z1:g} m"
            why = f"pose {i} is at z = {poses[i, 2]:g} m; the map is at {where}"
        elif close.any():
            i = int(np.argmax(close))
            why = (f"pose {i} puts the sensor {1e3 * gap[i]:.1f} mm from a wall or object; the map reaches "
                   f"{1e3 * self.wall_gap_m:g} mm")
        return ~(off_z | close), why

    # ------------------------------------------------------------------ file
    def meta(self) -> dict:
        return {"format": MAP_FORMAT, "sensor": self.sensor.to_dict(), **scene_record(self.tank, self.objects),
                "z_m": (list(self.z_range_m) if self.band else float(self.z_m)), "wall_gap_m": self.wall_gap_m,
                "warp_m": self.warp_m,
                "bem_options": {k: v for k, v in self.bem_options.items() if isinstance(v, (int, float, str))},
                "code": self.code, "history": self.history, "sigma_S_per_m": self.sigma_S_per_m}

    def save(self, path) -> Path:
        """One ``.npz``: arrays, and the scene, sensor, options and code version as JSON (written atomically)."""
        path = Path(path)
        partial = path.with_name(f"{path.name}.{os.getpid()}.writing.npz")
        np.savez(partial, nodes=self.nodes, K_nodes=self.K_nodes, K_free=self.K_free, X=self.fitted["X"],
                 coef=self.fitted["coef"], loo=self.fitted["loo"], meta=json.dumps(self.meta()))
        partial.replace(path)
        return path


def _assemble(off: np.ndarray, n: int, iu) -> np.ndarray:
    """Symmetric (..., n, n) with zero row sums from its strict upper triangle (..., pairs)."""
    K = np.zeros(off.shape[:-1] + (n, n))
    K[..., iu[0], iu[1]] = off
    K = K + np.swapaxes(K, -1, -2)
    K[..., np.arange(n), np.arange(n)] = -K.sum(axis=-1)
    return K


def load_tank_map(path) -> TankMap:
    """A :class:`TankMap` from its file (reads arrays: no fit); refuses another format with a clear error."""
    from electrosense.meshes.sensor import SensorDescription

    path = Path(path)
    try:
        with np.load(path) as z:
            meta = json.loads(str(z["meta"]))
            arrays = {k: z[k] for k in ("nodes", "K_nodes", "K_free", "X", "coef", "loo")}
    except (OSError, KeyError, ValueError, EOFError) as exc:
        raise ValueError(f"{path}: not a tank map ({exc})") from None
    if meta.get("format") != MAP_FORMAT:
        raise ValueError(f"{path}: not a tank map of this version (format {meta.get('format')!r}, expected "
                         f"{MAP_FORMAT!r}); build it again")
    try:
        tank, objects = scene_from_record(meta)
        sensor = SensorDescription.from_dict(meta["sensor"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: the map's scene cannot be read ({exc})") from None
    z = meta["z_m"]
    return TankMap(sensor, tank, tuple(z) if isinstance(z, list) else float(z), arrays["nodes"], arrays["K_nodes"],
                   arrays["K_free"], objects, meta.get("bem_options", {}), meta.get("code", ""),
                   float(meta.get("wall_gap_m", 0.005)), meta.get("history", []), meta.get("sigma_S_per_m"),
                   float(meta.get("warp_m", DEFAULT_WARP_M)),
                   {"X": arrays["X"], "coef": arrays["coef"], "loo": arrays["loo"]})


# ------------------------------------------------------------------ build
_WORKER = {}


def _worker_init(sensor, tank, objects, focus, options):
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from electrosense.bem import PoseSweep

    _WORKER["sweep"] = PoseSweep(sensor, tank, objects, sigma_S_per_m=1.0, focus_m=focus, **options)


def _worker_solve(poses):
    """K at ``poses``, this process's id and its CPU seconds so far (its set-up included)."""
    K = _WORKER["sweep"].conductance(poses).K_S
    return K, os.getpid(), time.process_time()


class _BemPool:
    """The BEM at many poses on ``workers`` processes (each with its own PoseSweep on the same tank mesh, so a
    pose's K does not depend on which worker solved it). ``cpu_s``: CPU seconds of the worker processes (with
    one worker everything runs in this process, whose own CPU time counts it)."""

    def __init__(self, sensor, tank, objects, focus, options, workers: int):
        self.args = (sensor, tank, tuple(objects), focus, options)
        self.workers = max(1, int(workers))
        self._cpu = {}
        self.solved = 0
        self._pool = None
        if self.workers > 1:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor

            # spawn (OpenMP forbids fork): a script that builds a map with workers needs `if __name__ == "__main__":`
            self._pool = ProcessPoolExecutor(self.workers, mp.get_context("spawn"), _worker_init, self.args)
        else:
            _worker_init(*self.args)

    @property
    def cpu_s(self) -> float:
        return float(sum(self._cpu.values()))

    def solve(self, poses: np.ndarray) -> np.ndarray:
        self.solved += len(poses)
        if self._pool is None:
            return _worker_solve(poses)[0]
        parts = [p for p in np.array_split(poses, self.workers) if len(p)]
        out = list(self._pool.map(_worker_solve, parts))
        for _, pid, cpu in out:
            self._cpu[pid] = max(cpu, self._cpu.get(pid, 0.0))
        return np.concatenate([K for K, _, _ in out])

    def close(self):
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)


def build_tank_map(sensor, tank, z_m, path=None, objects=(), target: float = TARGET_RMS,
                   target_max: float = TARGET_MAX, wall_gap_m: float = 0.005, spacing_m: float = 0.01,
                   n_headings: int = 48, n_depths: int = 5, first: int = 60, per_round: int = 24,
                   max_seconds: float = 270.0, max_cpu_seconds: float | None = None, bem_options: dict | None = None,
                   sigma_S_per_m: float | None = None, workers: int = 2, warp_m: float = DEFAULT_WARP_M,
                   progress=None) -> TankMap:
    """Build (or resume, from ``path``) the map of ``sensor`` in ``tank`` at depth ``z_m`` (module doc).

    ``z_m``: a depth (m, tank frame) or ``(z_min, z_max)`` for a band (``n_depths`` candidate depths);
    ``target`` / ``target_max``: the RMS and largest estimated relative error of a receiver current over the
    candidates at which the build stops; ``max_cpu_seconds``: CPU budget of the whole build, every process
    counted (default ``workers * max_seconds``: on a machine busy with other work the same command solves the
    same BEM poses and gives the same map); ``max_seconds``: wall-clock budget; at either the map is saved as it
    stands, its estimated error with it (a round is not started that the CPU budget cannot pay for);
    ``workers``: processes solving the BEM.
    """
    from electrosense.meshes.scene_mesh import trajectory_focus_m
    from electrosense.validation.diagnosis.anchored import default_bem_options
    from electrosense.validation.simulation.models import code_version, free_space_bem

    say = progress or (lambda s: None)
    t0, c0 = time.perf_counter(), time.process_time()
    max_cpu_seconds = workers * max_seconds if max_cpu_seconds is None else max_cpu_seconds
    objects = tuple(objects)
    options = default_bem_options(sensor, bem_options)
    code = code_version()
    band = np.ndim(z_m) > 0
    if band:
        z0, z1 = sorted(float(v) for v in z_m)
        z_m = (z0, z1)
        depths = np.linspace(z0, z1, max(2, n_depths))
    else:
        z_m = float(z_m)
        depths = np.array([z_m])
    C = reachable_poses(sensor, tank, depths, wall_gap_m, spacing_m, n_headings, objects)
    if not len(C):
        raise ValueError(f"no pose at depth z = {z_m} m keeps the sensor {wall_gap_m} m from the walls")
    frame = MapFrame(sensor, tank, objects, band, warp_m)
    F = frame.features(C)
    if frame.symmetric:   # one candidate per folded pose
        _, keep = np.unique(np.round(F / 1e-6).astype(np.int64), axis=0, return_index=True)
        C, F = C[np.sort(keep)], F[np.sort(keep)]
    say(f"{len(C)} candidate poses (grid {spacing_m} m, {n_headings} headings, {len(depths)} depth(s), "
        f"{wall_gap_m * 1e3:g} mm from the walls{', folded by the tank symmetry' if frame.symmetric else ''})")
    K_free = free_space_bem(sensor, options.get("edge_length_m")).K_S
    nodes, K_nodes, history = np.zeros((0, 4)), np.zeros((0,) + K_free.shape), []
    if path is not None and Path(path).exists():
        try:
            old = load_tank_map(path)
        except ValueError as exc:
            raise ValueError(f"{exc}; remove it or choose another output file") from None
        same = (old.sensor.to_dict() == sensor.to_dict() and same_scene(old.tank, old.objects, tank, objects, 1e-12)
                and old.z_m == z_m and old.code == code and old.warp_m == warp_m
                and old.bem_options == {k: v for k, v in options.items() if isinstance(v, (int, float, str))})
        if not same:
            raise ValueError(f"{path} holds a map of another scene, depth, BEM or code version; remove it or "
                             "choose another output file")
        nodes, K_nodes, history = old.nodes, old.K_nodes, list(old.history)
        say(f"resuming from {len(nodes)} BEM poses in {path}")
    focus = trajectory_focus_m(sensor, C[_farthest_points(F, 400)])
    pool = _BemPool(sensor, tank, objects, focus, options, workers)
    prior_cpu = float(history[-1].get("cpu_seconds", 0.0)) if history else 0.0
    prior_wall = float(history[-1].get("seconds", 0.0)) if history else 0.0

    def solve(idx):
        nonlocal nodes, K_nodes
        K = pool.solve(C[idx])
        nodes, K_nodes = np.vstack([nodes, C[idx]]), np.vstack([K_nodes, K])

    try:
        if len(nodes) < first:
            say(f"BEM at {first - len(nodes)} first poses on {pool.workers} process(es)")
            solve(_farthest_points(F, first - len(nodes), frame.features(nodes) if len(nodes) else None))
        while True:
            m = TankMap(sensor, tank, z_m, nodes, K_nodes, K_free, objects, options, code, wall_gap_m, history,
                        sigma_S_per_m, warp_m)
            err = m.estimated_error(C).max(axis=1)
            rms = float(np.sqrt(np.mean(err**2)))
            wall = prior_wall + time.perf_counter() - t0
            cpu = prior_cpu + time.process_time() - c0 + pool.cpu_s
            history.append({"bem_poses": len(nodes), "max_error": float(err.max()), "rms_error": rms,
                            "seconds": wall, "cpu_seconds": cpu})
            m.history = history
            if path is not None:
                m.save(path)
            say(f"{len(nodes)} BEM poses: estimated error RMS {100 * rms:.4f} %, max {100 * err.max():.4f} % "
                f"(target {100 * target:.4f} % / {100 * target_max:.4f} %), {wall:.0f} s")
            if rms <= target and err.max() <= target_max:
                break
            per_pose = (cpu - prior_cpu) / max(pool.solved, 1)   # set-up included: an upper estimate
            if time.perf_counter() - t0 > max_seconds or cpu + per_round * per_pose > max_cpu_seconds:
                say(f"time budget spent ({wall:.0f} s of {max_seconds:.0f} s wall, {cpu:.0f} s of "
                    f"{max_cpu_seconds:.0f} s CPU): the map is saved with its estimated error")
                break
            worst = np.argsort(err)[::-1][: 20 * per_round]
            solve(worst[_farthest_points(F[worst], per_round, m._X)])
    finally:
        pool.close()
    return m


# ------------------------------------------------------------------ as a model
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
        inside, why = m.covers(poses)
        if not inside.all():
            raise ValueError(why)
        return ConductanceMatrix(m.conductance(poses, self.sigma_S_per_m), m.sensor.emitter, self.sigma_S_per_m,
                                 {"model": "map", "bem_poses": int(len(m.nodes))})
