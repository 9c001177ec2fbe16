"""The candidate library: physical, parametrised additions to the simulation.

Each candidate changes what is simulated, never the curve itself:

=====================  ===========================================  ==========================
name                   what changes (parameters)                    how it is evaluated
=====================  ===========================================  ==========================
``conductivity``       sigma -> sigma (1 + s)         (s)           exact: K is linear in sigma
``temperature_drift``  sigma (1 + b (t - t_ref)) or                 exact
                       sigma (1 + alpha (T - T_ref)) (b or alpha)
``contact_impedance``  z_c on every electrode (common: z; per        series network on K
                       electrode: z_1..z_n, ohm m^2)                (z_c / BEM-fitted area)
``channel_gain``       receiver k reads (1 + g_k) I_k (g_1..g_m)    exact
``pose_offset``        robot frame shifted/turned against the tank  the BEM's pose gradient
                       (dx, dy, dyaw; or the sensor mounted off     (Taylor step from the
                       its logged pose; nested forms: the heading   baseline; effect model when
                       alone, the frame's turn alone, the shift)    the scene changes too)
``water_depth``        free surface (or floor) elsewhere (dd)       effect model corrected to
``tank_size``          walls elsewhere (dLx, dLy; or one alone)     the BEM's shape derivative
``unmodelled_object``  a sphere at (x, y, z) of dipole chi b^3      the BEM's field (multipoles)
``none``               nothing: the gap is noise                    --
=====================  ===========================================  ==========================

Geometric effects are evaluated with an *effect model* (the PSM with its
spheres at the electrodes' centres, fast and vectorised) as a relative change
of each entry of the baseline's K (the BEM or the PSM at the logged poses):
``K = K_base * K_eff(changed) / K_eff(nominal)`` (zero row sums restored).
When the baseline *is* the effect model this is the effect model itself.
Then the water's conductivity scales K, the contact impedance is put in series,
and the channel gains scale the receivers' readings: the order of the physics.

Example
-------
>>> lib = library()
>>> sorted(lib)[:3]
['channel_gain', 'conductivity', 'contact_impedance']
>>> [f.form for f in lib["pose_offset"]]
['frame', 'mount', 'heading', 'turn', 'shift']

A form with fewer parameters is scored beside the full one (the information criterion charges each
parameter): a log that determines a heading offset but not a shift is explained by the heading alone.
"""
from __future__ import annotations

import hashlib
import warnings
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from electrosense.meshes.objects import Sphere
from electrosense.meshes.tank import Tank
from electrosense.validation.bench.virtual.effects import EFFECT_NAMES as BENCH_EFFECT_NAMES
from electrosense.validation.diagnosis.forward import electrode_areas_m2, receiver_currents, series_contact
from electrosense.validation.diagnosis.observations import Observations

__all__ = ["EFFECT_NAMES", "Scenario", "Problem", "Effect", "library", "restricted", "combined_scales", "combined_bounds",
           "model_trust_weights"]

#: Candidate names, in the order they are reported: the virtual bench's effects (defined once, in
#: :mod:`electrosense.validation.bench.virtual.effects`) and ``none``.
EFFECT_NAMES = tuple(BENCH_EFFECT_NAMES) + ("none",)


# ----------------------------------------------------------------------- scenarios
@dataclass
class Scenario:
    """What is simulated for a subset of the samples."""

    poses: np.ndarray  # (p, 4)
    tank: Tank | None
    objects: tuple
    sigma_scale: np.ndarray  # (p,)
    contact_ohm_m2: np.ndarray | None  # (n,)
    gain: np.ndarray  # (m,)
    geometry_changed: bool = False
    rows: np.ndarray | None = None  # (p,) the sample indices it holds (sorted); None: those asked for


@dataclass
class Problem:
    """Observations + baseline simulation + effect model: everything a prediction needs.

    Parameters
    ----------
    obs : Observations
    K_base : (P, n, n)
        The baseline model's K at the logged poses, nominal physics.
    effect_model : callable ``(poses, tank, objects) -> K`` (P, n, n)
        The fast model used for geometric changes.
    K_effect0 : (P, n, n), optional
        ``effect_model`` at the logged poses, nominal scene (computed if absent).
    weight : (P, m), optional
        Weights of the relative residuals in the fits and scores (default 1):
        s / sqrt(s^2 + model error^2), see :func:`model_trust_weights`.
    pose_gradient : PoseGradient, optional
        The BEM's d log K / d(x, y, yaw) at the logged poses
        (:mod:`electrosense.validation.diagnosis.pose_gradient`): the sensor's
        move is then predicted from the baseline itself, not through the
        effect model.
    wall_gradient : WallGradient, optional
        The BEM's correction of the effect model's change of K with the
        walls, floor and free surface (:mod:`electrosense.validation.diagnosis.wall_gradient`).
    object_field : ObjectField, optional
        The change of K that a sphere added by a candidate makes, from the
        BEM's field where it sits (:mod:`electrosense.validation.diagnosis.object_field`);
        without it, through the effect model.
    secants : dict
        Effect label -> :class:`~electrosense.validation.diagnosis.bem_secant.SecantCorrection`:
        what the BEM of a candidate's fitted scene adds to its prediction
        (applied by :func:`electrosense.validation.diagnosis.fitting.predict`).
    """

    obs: Observations
    K_base: np.ndarray
    effect_model: Callable
    K_effect0: np.ndarray | None = None
    baseline_name: str = ""
    weight: np.ndarray | None = None
    pose_gradient: object = None
    wall_gradient: object = None
    object_field: object = None
    secants: dict = field(default_factory=dict)
    t_ref_s: float = field(init=False)
    T_ref_C: float | None = field(init=False)
    areas_m2: np.ndarray = field(init=False)

    def __post_init__(self):
        obs = self.obs
        n = obs.sensor.n_electrodes
        self.K_base = np.asarray(self.K_base, float).reshape(obs.n_poses, n, n)
        if self.K_effect0 is None:
            self.K_effect0 = self.effect_model(obs.poses, obs.tank, tuple(obs.objects))
        self.t_ref_s = float(np.mean(obs.t_s))
        T0 = obs.meta.get("temperature_C") if isinstance(obs.meta, dict) else None
        if obs.temperature_C is not None:
            self.T_ref_C = float(T0) if isinstance(T0, (int, float)) else float(np.mean(obs.temperature_C))
        else:
            self.T_ref_C = None
        self.areas_m2 = electrode_areas_m2(obs.sensor)
        self._effective_areas = None
        self._memo = {self._scene_key(obs.poses, obs.tank, obs.objects): self.K_effect0}
        self.I_base = receiver_currents(self.K_base, obs.emitter) * obs.U_V[:, None]
        if self.weight is None:
            self.weight = np.ones_like(self.I_base)
        if np.any(np.abs(self.I_base) == 0):
            raise ValueError("the baseline simulation gives a zero receiver current: cannot form relative residuals")

    # -------------------------------------------------------------------------
    def nominal(self, idx: np.ndarray) -> Scenario:
        obs = self.obs
        return Scenario(
            poses=obs.poses[idx].copy(), tank=obs.tank, objects=tuple(obs.objects),
            sigma_scale=np.ones(len(idx)), contact_ohm_m2=None, gain=np.ones(obs.n_receivers),
            rows=np.asarray(idx),
        )

    def predict(self, scenario: Scenario, idx: np.ndarray) -> np.ndarray:
        """Receiver currents (p, m) of ``scenario`` for the samples ``idx``.

        ``scenario`` may hold more samples than ``idx`` (its ``rows``, sorted):
        the effect model is then evaluated at all of them once per scene
        (memoised: a training set and its held-out set at one parameter
        vector cost one evaluation), and only where that scene refuses a
        pose outside ``idx`` at ``idx`` alone.
        """
        idx = np.asarray(idx)
        rows = scenario.rows
        at = slice(None) if rows is None or (len(rows) == len(idx) and np.array_equal(rows, idx)) \
            else np.searchsorted(rows, idx)
        K = self.K_base[idx]
        if not scenario.geometry_changed:
            return self.currents(K, scenario, at, idx)
        poses = scenario.poses[at]
        added = self._added_spheres(scenario)
        if added:   # the spheres a candidate adds come from the BEM's field (:mod:`.object_field`), the rest below
            scenario = replace(scenario, objects=tuple(self.obs.objects))
        if self.pose_gradient is not None:
            # the sensor's move in the believed scene: the BEM's own change of K with pose (Taylor step)
            K = self.pose_gradient.moved(K, idx, self.obs.poses[idx], poses)
            if not self._moves_pose_only(scenario):
                # the rest of the scene's change, as the effect model sees it at the moved poses
                held = self.obs.poses[scenario.rows if scenario.rows is not None else idx]
                moved_only = np.column_stack([scenario.poses[:, :2], held[:, 2], scenario.poses[:, 3]])
                believed = replace(scenario, poses=moved_only, tank=self.obs.tank, objects=tuple(self.obs.objects))
                K = K * (self._effect_K_at(scenario, at) / self._effect_K_at(believed, at))
        elif not (added and self._moves_pose_only(scenario) and np.array_equal(poses, self.obs.poses[idx])):
            # relative change of every entry of K, as the effect model sees it
            K = K * (self._effect_K_at(scenario, at) / self.K_effect0[idx])
        if self.wall_gradient is not None and scenario.tank is not None:
            # the walls' part corrected to the BEM's first order (:mod:`.wall_gradient`)
            from electrosense.validation.diagnosis.pose_gradient import apply_pair_log
            from electrosense.validation.diagnosis.wall_gradient import wall_parameters

            theta = wall_parameters(self.obs, scenario.tank, poses, idx)
            if np.any(theta):
                K = apply_pair_log(K, self.wall_gradient.log_change(idx, theta))
        n = K.shape[-1]
        off = K * (1 - np.eye(n))   # zero row sums restored
        K = off - np.eye(n) * off.sum(axis=-1, keepdims=True)
        if added:
            K = K + self.object_field(poses, scenario.tank, added)
        return self.currents(K, scenario, at, idx)

    def _added_spheres(self, scenario: Scenario) -> tuple:
        """The spheres ``scenario`` holds beyond the believed objects, when the BEM's field can give their change
        (an :class:`~.object_field.ObjectField` and a box tank or unbounded water); else ()."""
        known = tuple(self.obs.objects)
        objects = tuple(scenario.objects)
        if self.object_field is None or len(objects) <= len(known) or objects[:len(known)] != known:
            return ()
        added = objects[len(known):]
        if not all(isinstance(o, Sphere) for o in added) or not (scenario.tank is None or isinstance(scenario.tank,
                                                                                                   Tank)):
            return ()
        return added

    def _moves_pose_only(self, scenario: Scenario) -> bool:
        """Whether ``scenario`` differs from the believed scene by the sensor's pose alone (x, y, yaw)."""
        return scenario.tank == self.obs.tank and tuple(scenario.objects) == tuple(self.obs.objects)

    def currents(self, K: np.ndarray, scenario: Scenario, at, idx: np.ndarray, contact: bool = True) -> np.ndarray:
        """Receiver currents (p, m) from the scene's K (p, n, n) at unit water scale: then the water's conductivity,
        the contact impedance in series (unless ``contact`` is False: already in K) and the channel gains."""
        K = K * np.asarray(scenario.sigma_scale)[at][:, None, None]
        if contact and scenario.contact_ohm_m2 is not None:
            z = np.asarray(scenario.contact_ohm_m2, float)
            K = series_contact(K, z / self.contact_areas_m2(z))
        I = receiver_currents(K, self.obs.emitter) * self.obs.U_V[idx, None]
        return I * scenario.gain[None, :]

    def _effect_K_at(self, scenario: Scenario, at) -> np.ndarray:
        """The effect model's K of ``scenario`` at its rows ``at`` (every row's scene evaluated once)."""
        if isinstance(at, slice):
            return self._effect_K(scenario)
        try:
            return self._effect_K(scenario)[at]
        except (ValueError, np.linalg.LinAlgError, FloatingPointError):  # refused at a row not asked for
            return self._effect_K(replace(scenario, poses=scenario.poses[at], rows=None))

    def _effect_K(self, scenario: Scenario) -> np.ndarray:
        """The effect model's K for a changed scene, memoised (finite differences along the other,
        non-geometric parameters ask for the same scene again; the nominal scene is ``K_effect0``; a scene
        the model refuses is remembered as refused)."""
        key = self._scene_key(scenario.poses, scenario.tank, scenario.objects)
        K = self._memo.get(key)
        if K is None:
            try:
                K = self.effect_model(scenario.poses, scenario.tank, scenario.objects)
            except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
                K = exc
            if len(self._memo) >= 256:
                self._memo.pop(next(iter(self._memo)))
            self._memo[key] = K
        if isinstance(K, Exception):
            raise K
        return K

    @staticmethod
    def _scene_key(poses, tank, objects) -> tuple:
        return hashlib.sha1(np.ascontiguousarray(poses, float).tobytes()).hexdigest(), tank, tuple(objects)

    def contact_areas_m2(self, z_ohm_m2) -> np.ndarray:
        """Areas (n,) of the lumped contact z / A that reproduce the BEM's contact boundary condition
        (:mod:`electrosense.validation.diagnosis.contact`); the geometric areas if the BEM cannot be run."""
        if self._effective_areas is None:
            try:
                from electrosense.validation.diagnosis.contact import effective_areas

                self._effective_areas = effective_areas(self.obs.sensor, self.obs.sigma_S_per_m)
            except Exception as exc:  # say so: the geometric areas are 10-20 % off at small z_c
                warnings.warn(f"contact impedance: the BEM's effective areas failed ({exc}); the effect model falls "
                              "back to the electrodes' geometric areas (10-20 % off at small z_c)", RuntimeWarning,
                              stacklevel=2)
                self._effective_areas = lambda z: self.areas_m2
        return self._effective_areas(z_ohm_m2)

    def relative_residual(self, I_pred: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """(bench - prediction) / |baseline| for the samples ``idx``: (p, m)."""
        return (self.obs.currents_A[idx] - I_pred) / np.abs(self.I_base[idx])


def model_trust_weights(problem: Problem, noise: float, model_error: float = 0.1) -> np.ndarray:
    """Weights (P, m) that trust each sample as far as the effect model can be trusted there.

    Models agree least where the tank matters most (a sensor tip a few
    centimetres from a wall: the PSM and the BEM differ by several percent
    there, and so do their sensitivities to the tank and the pose). The
    sample's standard deviation is taken as sqrt(s^2 + (model_error * D)^2)
    with D the relative change of the receiver current that the tank causes
    (effect model, tank vs unbounded water); the weight is s over that.
    """
    obs = problem.obs
    if obs.tank is None or model_error <= 0:
        return np.ones_like(problem.I_base)
    free = receiver_currents(problem.effect_model(obs.poses, None, tuple(obs.objects)), obs.emitter)
    tank = receiver_currents(problem.K_effect0, obs.emitter)
    D = np.abs(tank / free - 1.0)
    return noise / np.sqrt(noise**2 + (model_error * D) ** 2)


# -------------------------------------------------------------------------- effects
@dataclass(frozen=True)
class Effect:
    """One form of a candidate effect.

    ``apply(theta, scenario, problem, idx) -> scenario`` adds the effect with
    physical parameters ``theta`` (units in ``units``). ``scales`` are typical
    magnitudes (the fit works in ``theta / scales``), ``lower``/``upper``
    physical bounds. ``order`` fixes the order in which combined effects are
    applied (objects are placed in the believed frame before the frame moves).
    """

    name: str
    form: str
    param_names: tuple
    units: tuple
    scales: tuple
    lower: tuple
    upper: tuple
    apply: Callable = field(compare=False, repr=False)
    geometric: bool = False
    order: int = 10
    describe: str = ""
    local: bool = False  # seen by a part of the log only (an object): held out by segments, not whole passes

    @property
    def n_params(self) -> int:
        return len(self.param_names)

    @property
    def label(self) -> str:
        return self.name if self.form == "" else f"{self.name}[{self.form}]"


def restricted(effect: Effect, keep: tuple, form: str, describe: str) -> Effect:
    """``effect`` with only the parameters ``keep`` (indices) free, the others held at zero: a nested form.

    A candidate whose parameters the log does not all determine (a tank longer but not wider; a heading
    offset without a shift) is then scored with the parameters it needs: a held-out fold cannot move a
    parameter its training passes do not see, and the information criterion charges only what is fitted.

    >>> lib = library()
    >>> restricted(lib["tank_size"][0], (0,), "x", "walls at x moved").param_names
    ('dLx_m',)
    """
    keep = tuple(int(k) for k in keep)
    full_apply, n = effect.apply, effect.n_params

    def apply(theta, sc, pb, idx):
        full = np.zeros(n)
        full[list(keep)] = theta
        return full_apply(full, sc, pb, idx)

    def pick(values):
        return tuple(values[k] for k in keep)

    return replace(effect, form=form, param_names=pick(effect.param_names), units=pick(effect.units),
                   scales=pick(effect.scales), lower=pick(effect.lower), upper=pick(effect.upper), apply=apply,
                   describe=describe)


def combined_scales(effects) -> np.ndarray:
    return np.concatenate([np.asarray(e.scales, float) for e in effects]) if effects else np.zeros(0)


def combined_bounds(effects) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) physical bounds of the concatenated parameters of ``effects``."""
    if not effects:
        return np.zeros(0), np.zeros(0)
    return (np.concatenate([np.asarray(e.lower, float) for e in effects]),
            np.concatenate([np.asarray(e.upper, float) for e in effects]))


def _conductivity(theta, sc, pb, idx):
    sc.sigma_scale = sc.sigma_scale * (1.0 + theta[0])
    return sc


def _drift_time(theta, sc, pb, idx):
    sc.sigma_scale = sc.sigma_scale * (1.0 + theta[0] * (pb.obs.t_s[idx] - pb.t_ref_s) / 3600.0)
    return sc


def _drift_temperature(theta, sc, pb, idx):
    sc.sigma_scale = sc.sigma_scale * (1.0 + theta[0] * (pb.obs.temperature_C[idx] - pb.T_ref_C))
    return sc


def _gain(theta, sc, pb, idx):
    sc.gain = sc.gain * (1.0 + np.asarray(theta, float))
    return sc


def _contact(theta, sc, pb, idx):
    n = pb.obs.sensor.n_electrodes
    z = np.broadcast_to(np.asarray(theta, float), (n,))
    sc.contact_ohm_m2 = z if sc.contact_ohm_m2 is None else sc.contact_ohm_m2 + z
    return sc


def _pose_offset(theta, sc, pb, idx):
    dx, dy, dyaw = theta
    c, s = np.cos(dyaw), np.sin(dyaw)
    p = sc.poses.copy()
    x, y = p[:, 0].copy(), p[:, 1].copy()
    p[:, 0] = c * x - s * y + dx
    p[:, 1] = s * x + c * y + dy
    p[:, 3] = p[:, 3] + dyaw
    sc.poses, sc.geometry_changed = p, True
    return sc


def _pose_offset_additive(theta, sc, pb, idx):
    dx, dy, dyaw = theta
    p = sc.poses.copy()
    p[:, 0] += dx
    p[:, 1] += dy
    p[:, 3] += dyaw
    sc.poses, sc.geometry_changed = p, True
    return sc


def _reframe_depth(sc, floor_z: float, surface_z: float):
    """Water between ``floor_z`` and ``surface_z`` (believed frame): a new tank, poses/objects re-framed."""
    lx, ly, _ = sc.tank.size_m
    depth = surface_z - floor_z
    if not depth > 0:
        raise ValueError("water depth would be negative")
    shift = -0.5 * depth - floor_z
    p = sc.poses.copy()
    p[:, 2] += shift
    objs = tuple(replace(o, centre_m=(o.centre_m[0], o.centre_m[1], o.centre_m[2] + shift)) for o in sc.objects)
    sc.tank, sc.poses, sc.objects, sc.geometry_changed = Tank((lx, ly, depth), depth), p, objs, True
    return sc


def _depth_surface(theta, sc, pb, idx):
    return _reframe_depth(sc, sc.tank.floor_z_m, sc.tank.free_surface_z_m + theta[0])


def _depth_floor(theta, sc, pb, idx):
    return _reframe_depth(sc, sc.tank.floor_z_m + theta[0], sc.tank.free_surface_z_m)


def _tank_size(theta, sc, pb, idx):
    lx, ly, lz = sc.tank.size_m
    sc.tank = Tank((lx + theta[0], ly + theta[1], lz), sc.tank.water_depth_m)
    sc.geometry_changed = True
    return sc


def object_sphere(theta, sigma_S_per_m: float) -> Sphere | None:
    """The sphere with dipole strength ``theta[3]`` (m^3) at ``theta[:3]``: conducting if > 0, insulating if < 0."""
    x, y, z, m = theta
    if m == 0:
        return None
    if m > 0:
        return Sphere((x, y, z), conductivity_S_per_m=np.inf, radius_m=float(m) ** (1 / 3), name="unmodelled")
    return Sphere((x, y, z), conductivity_S_per_m=0.0, radius_m=float(-2 * m) ** (1 / 3), name="unmodelled")


def _object(theta, sc, pb, idx):
    sphere = object_sphere(theta, pb.obs.sigma_S_per_m)
    if sphere is not None:
        if sc.tank is not None and sc.tank.distance_to_boundary_m(np.asarray(sphere.centre_m)[None]).min() \
                < sphere.radius_m:
            raise ValueError("the object would reach out of the water")  # the fit is refused there
        sc.objects = tuple(sc.objects) + (sphere,)
    sc.geometry_changed = True
    return sc


def _none(theta, sc, pb, idx):
    return sc


def library(obs: Observations | None = None) -> dict[str, list[Effect]]:
    """All candidates, by name; each a list of forms (alternative parametrisations).

    Candidates that cannot apply to ``obs`` are left out (no tank: no
    ``water_depth``/``tank_size``; no logged temperature: the temperature form
    of ``temperature_drift``).
    """
    n = obs.sensor.n_electrodes if obs is not None else 4
    m = n - 1
    lib: dict[str, list[Effect]] = {}
    lib["conductivity"] = [
        Effect("conductivity", "", ("sigma_rel_change",), ("1",), (0.01,), (-0.5,), (1.0,), _conductivity,
               describe="sigma_true = sigma_believed (1 + s)")
    ]
    drift = [
        Effect("temperature_drift", "time", ("drift_per_hour",), ("1/h",), (0.01,), (-1.0,), (1.0,), _drift_time,
               describe="sigma(t) = sigma (1 + b (t - t_mean))")
    ]
    if obs is None or obs.has_temperature:
        drift.append(
            Effect("temperature_drift", "temperature", ("alpha_per_K",), ("1/K",), (0.02,), (-0.2,), (0.2,),
                   _drift_temperature, describe="sigma(T) = sigma (1 + alpha (T - T_ref)), alpha about 0.02/K")
        )
    lib["temperature_drift"] = drift
    lib["contact_impedance"] = [
        Effect("contact_impedance", "common", ("z_c_ohm_m2",), ("ohm m^2",), (1e-3,), (0.0,), (10.0,), _contact,
               describe="one contact impedance in series with every electrode (z_c / A_eff, the effective areas "
                        "fitted to the BEM with the contact boundary condition)"),
        Effect("contact_impedance", "per_electrode", tuple(f"z_c{k}_ohm_m2" for k in range(1, n + 1)),
               ("ohm m^2",) * n, (1e-3,) * n, (0.0,) * n, (10.0,) * n, _contact,
               describe="a contact impedance per electrode"),
    ]
    receivers = obs.sensor.receivers if obs is not None else tuple(range(1, m + 1))
    lib["channel_gain"] = [
        Effect("channel_gain", "", tuple(f"gain_rel_change_I{k}" for k in receivers), ("1",) * m, (0.01,) * m,
               (-0.5,) * m, (0.5,) * m, _gain,
               describe="receiver k reads (1 + g_k) times its current (a gain common to all receivers cannot be "
                        "told from a conductivity change: see the confusable pairs)")
    ]
    lib["pose_offset"] = [
        Effect("pose_offset", "frame", ("dx_m", "dy_m", "dyaw_rad"), ("m", "m", "rad"), (0.005, 0.005, 0.01),
               (-0.05, -0.05, -0.2), (0.05, 0.05, 0.2), _pose_offset, geometric=True, order=1,
               describe="robot frame turned and shifted: true position = rotation(dyaw) logged position + (dx, dy), "
                        "true yaw = logged yaw + dyaw"),
        Effect("pose_offset", "mount", ("dx_m", "dy_m", "dyaw_rad"), ("m", "m", "rad"), (0.005, 0.005, 0.01),
               (-0.05, -0.05, -0.2), (0.05, 0.05, 0.2), _pose_offset_additive, geometric=True, order=1,
               describe="sensor mounted off the logged pose: true pose = logged pose + (dx, dy, dyaw)"),
    ]
    lib["pose_offset"] += [
        restricted(lib["pose_offset"][1], (2,), "heading", "sensor turned on its mount: true yaw = logged yaw + dyaw"),
        restricted(lib["pose_offset"][0], (2,), "turn", "robot frame turned about the tank's origin: true position "
                   "= rotation(dyaw) logged position, true yaw = logged yaw + dyaw"),
        restricted(lib["pose_offset"][1], (0, 1), "shift", "robot frame shifted: true position = logged + (dx, dy)"),
    ]
    if obs is None or obs.tank is not None:
        depth = obs.tank.water_depth_m if obs is not None else 1.0
        lxy = obs.tank.size_m[:2] if obs is not None else (1.0, 1.0)
        lib["water_depth"] = [
            Effect("water_depth", "surface", ("d_surface_m",), ("m",), (0.01,), (-0.4 * depth,), (0.4 * depth,),
                   _depth_surface, geometric=True, order=3, describe="free surface higher by d than believed"),
            Effect("water_depth", "floor", ("d_floor_m",), ("m",), (0.01,), (-0.4 * depth,), (0.4 * depth,),
                   _depth_floor, geometric=True, order=3, describe="floor higher by d than believed"),
        ]
        both = Effect("tank_size", "", ("dLx_m", "dLy_m"), ("m", "m"), (0.01, 0.01),
                      (-0.2 * lxy[0], -0.2 * lxy[1]), (0.2 * lxy[0], 0.2 * lxy[1]), _tank_size, geometric=True,
                      order=2, describe="walls at +-(L + dL)/2 instead of +-L/2")
        lib["tank_size"] = [both,
                            restricted(both, (0,), "x", "walls at x = +-(Lx + dLx)/2 instead of +-Lx/2"),
                            restricted(both, (1,), "y", "walls at y = +-(Ly + dLy)/2 instead of +-Ly/2")]
    lo, hi = _object_bounds(obs)
    lib["unmodelled_object"] = [
        Effect("unmodelled_object", "", ("x_m", "y_m", "z_m", "dipole_m3"), ("m", "m", "m", "m^3"),
               (0.05, 0.05, 0.05, 1e-6), tuple(lo) + (-1e-3,), tuple(hi) + (1e-3,), _object, geometric=True, order=0,
               local=True,
               describe="a sphere of dipole strength chi b^3 (conducting if > 0, insulating if < 0) at (x, y, z)")
    ]
    lib["none"] = [Effect("none", "", (), (), (), (), (), _none, describe="nothing: the gap is noise")]
    return lib


def _object_bounds(obs: Observations | None):
    if obs is None:
        return (-1.0, -1.0, -1.0), (1.0, 1.0, 1.0)
    if obs.tank is not None:
        lo, hi = obs.tank.water_bounds_m
        margin = 0.01
        return tuple(lo + margin), tuple(hi - margin)
    lo = obs.poses[:, :3].min(axis=0) - 0.5
    hi = obs.poses[:, :3].max(axis=0) + 0.5
    return tuple(lo), tuple(hi)
