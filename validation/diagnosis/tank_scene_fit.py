"""A ring-electrode tank's unknowns fitted on the BEM across set-ups: the scene and the instrument together.

What a phantom's description leaves open is fitted to its measurements,
with standard errors and the directions the data cannot determine
(:func:`~electrosense.validation.diagnosis.scene_fit.fit_unknowns`):

* the scene (:func:`geometry_unknowns`, :func:`scene_at`): the tank's radius
  at the ring's height and its wall's slope (a pail's taper), the water
  depth, the ring's height, the ring electrodes' effective radius (a tack's
  head flat on the wall, or a screw's tip standing into the water, as the
  disc that draws the same current), the balls' radius and height;
* the instrument (:func:`instrument_unknowns`): one scale (the current's
  unit over the water's conductivity), a gain per class of (drive pair,
  measurement pair) by the parity of their places on the ring (a
  multiplexer's groups), a gain per measurement channel, a complex
  common-mode fraction read through a magnitude demodulator
  (:mod:`~electrosense.validation.diagnosis.common_mode`), and, where the scene
  has an electrode off the ring that is not floating (a ground), the
  fraction of the drive current that returns through it.

Data and noise model. Two blocks: the reference set-up's magnitudes
(training drives only), ``log |Z|`` against ``log`` of the instrument's
reading of the BEM, each row's error of one standard deviation, the
set-up's per-measurement reciprocity floor; and one ball set-up's
difference signal ``Z_ball / Z_ref - 1`` (every drive), whose gains cancel,
with the floor of that signal's own reciprocity; both with the BEM's own error
in quadrature (:func:`discretisation_error`: the fit's mesh against a finer one;
every set-up's tank is meshed alike, graded towards all the set-ups' balls, so
that a difference signal is not the difference of two meshes). Each fitted
unknown carries its standard error (the noise's, scaled by the fit's own
scatter), ``se_bem`` (how far the BEM's error moves it: a systematic, to first
order) and ``se_total`` (the two in quadrature). The fit is scored on what
it never saw: the reference's held-out drives (:func:`alternate_pair_folds`:
every multiplexer class has training drives) and the other ball set-ups,
each solved on the BEM at the fitted scene (the reference too: a signal is a
ratio of two set-ups' rows, and the surrogate's error on one of them would be
all of its error).

The description is a measurement too: each stated length is a Gaussian
prior about its stated value of the description's tolerance
(:func:`description_tolerance`, :data:`DESCRIPTION_TOLERANCE`; a scene file's
``[tolerance]`` table overrides it), and the fit maximises the posterior. The
data alone do not fix a scene's scale: a tank scaled as a whole, with its
balls shifted to the same places relative to the wall, fits an empty tank and
one ball set-up alike (the instrument's scale takes the rest) and predicts
set-ups elsewhere wrongly; the report marks an unknown whose standard error is
still above 0.7 of its tolerance, both scaled by the fit's scatter
(``set_by_prior``: the tolerance, not the data, sets it). The rows weigh the
data at their floors and the priors at their tolerances, as stated; where the
model misfits by more than the floor, the data weigh more than their scatter
warrants.

Few solves (:class:`SetupSurrogate`): the BEM's ``log |Z|`` of each fitted
set-up is linear in the geometry about an anchor, its derivatives from one
forward difference per unknown (one solve each, the mesh made anew). The fit
runs on that surrogate; the scene is then solved at the fitted geometry,
the surrogate moved there (its derivatives corrected by Broyden's secant
update) and the fit repeated, until the geometry's step is below its
standard errors (a chord Gauss-Newton: two solves per iteration). Every
step that would leave the water or put an electrode off the wall is
shortened (:func:`placeable_step`) and said.
Geometry the data do not place (no standard error, or a 95 % interval wider
than its bounds: :func:`unplaced`) is held at its stated value in a second
fit, and the fit of lower :func:`bic` kept (:meth:`_Fit.placed_chord`).

Example
-------
The gauge rows keep the channel gains' mean at zero (the scale carries it):

>>> gauge_rows(np.array([0.1, -0.1, 0.3]), 1e-3).round(1).tolist()
[300.0]
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from electrosense.bem.solve import solve_scene
from electrosense.meshes.cylinder_tank_mesh import disc_problems
from electrosense.meshes.scene_mesh import objects_focus_m
from electrosense.meshes.surface_electrodes import DiscElectrode
from electrosense.validation.comparison.study_mesh import BEM_ORDER, REFINE, refined_options
from electrosense.validation.comparison.transfer import (
    balls_at,
    model_transfer_ohm,
    ring_pair_places,
    setup_table,
    signal_floor,
    stated_balls,
)
from electrosense.validation.diagnosis.common_mode import common_mode_rows, instrument_reference
from electrosense.validation.diagnosis.scene_fit import Unknown, fit_unknowns, prior_rows, set_by_prior

__all__ = [
    "GEOMETRY_GROUPS",
    "SetupSurrogate",
    "alternate_pair_folds",
    "checked_tolerance",
    "description_tolerance",
    "fit_tank_scene",
    "gauge_rows",
    "geometry_unknowns",
    "instrument_unknowns",
    "placeable_step",
    "ring_state",
    "scene_at",
]

#: the geometry unknowns by what they describe (the names of :func:`geometry_unknowns`)
GEOMETRY_GROUPS = {"tank": ("ring_radius_m", "wall_slope", "water_depth_m"), "ring": ("ring_z_m",),
                   "electrode_size": ("electrode_radius_m",), "balls": ("ball_radius_m", "ball_z_m"),
                   "frame": ("frame_dx_m", "frame_dy_m", "frame_rotation_rad")}
#: a surrogate is first trusted this many typical steps (``Unknown.step``) about its anchor
TRUST = 2.0
#: robust loss of the fit (:func:`scipy.optimize.least_squares`): rows beyond F_SCALE times the typical misfit (the
#: noise floor, or the plain least-squares fit's own scatter where that is larger) weigh less
LOSS, F_SCALE = "soft_l1", 3.0
#: unknowns that only the set-ups with balls see
BALL_ONLY = ("ball_radius_m", "ball_z_m", "frame_dx_m", "frame_dy_m", "frame_rotation_rad")


def _ring_discs(scene, ring) -> list[int]:
    """0-based scene indices of the ring's electrodes, which must be discs on a cylindrical tank's wall."""
    tank = scene.tank
    if not hasattr(tank, "radius_at"):
        raise ValueError("the scene fit needs a cylindrical tank (the ring sits on its wall)")
    if not ring:
        raise ValueError("the scene fit needs the [protocol] table's ring")
    out = []
    for e in ring:
        el = scene.electrodes[int(e) - 1 - scene.n_sensor_electrodes]
        if not isinstance(el, DiscElectrode) or not tank.on_wall(el.centre_m):
            raise ValueError(f"the scene fit needs the ring's electrodes as discs on the wall: electrode {e} is not")
        out.append(int(e) - 1 - scene.n_sensor_electrodes)
    return out


def ring_state(scene, protocol) -> dict:
    """The stated geometry as the values of :func:`geometry_unknowns` (ring's mean height and radius...).

    >>> from electrosense.meshes import Scene; from electrosense.meshes.cylinder_tank import CylinderTank
    >>> s = Scene(None, tank=CylinderTank(0.15, 0.3, floor_radius_m=0.12),
    ...           electrodes=[DiscElectrode((0.13, 0.0, -0.05), 0.004), DiscElectrode((-0.13, 0.0, -0.05), 0.004)])
    >>> v = ring_state(s, {"ring": [1, 2], "ball_radius_m": 0.02, "ball_z_m": -0.05})
    >>> round(v["ring_radius_m"], 4), round(v["wall_slope"], 3), v["ring_z_m"], v["electrode_radius_m"]
    (0.13, 0.1, -0.05, 0.004)
    """
    tank = scene.tank
    idx = _ring_discs(scene, protocol.get("ring", []))
    z = float(np.mean([scene.electrodes[i].centre_m[2] for i in idx]))
    out = {"ring_radius_m": float(tank.radius_at(z)), "wall_slope": float(tank.wall_slope),
           "water_depth_m": float(tank.water_depth_m), "ring_z_m": z,
           "electrode_radius_m": float(np.mean([scene.electrodes[i].radius_m for i in idx]))}
    if "ball_radius_m" in protocol:
        balls = stated_balls(scene, protocol)
        out["ball_radius_m"], out["ball_z_m"] = balls["radius_m"], balls["z_m"]
        out.update(frame_dx_m=0.0, frame_dy_m=0.0, frame_rotation_rad=0.0)
    return out


#: what a description written by hand knows of each geometry unknown, one standard deviation in the unknown's
#: unit: the scene fit's Gaussian priors about the stated values (:func:`description_tolerance`; a scene file's
#: ``[tolerance]`` table overrides them). A length read off a ruler or a tape, 3 mm; a water mark, 5 mm; a
#: wall's taper, 0.05; a ball placed by hand on a line or a grid, 5 mm each way. None for the balls' height: a
#: phantom's description seldom states it (Ottawa's does not), and a scene file's value is then a guess.
DESCRIPTION_TOLERANCE = {"ring_radius_m": 0.003, "wall_slope": 0.05, "water_depth_m": 0.005, "ring_z_m": 0.003,
                         "frame_dx_m": 0.005, "frame_dy_m": 0.005}
#: ... and those relative to the stated value: a manufactured ball's radius, 2 %; a ring electrode's effective
#: radius (a screw's or a tack's head is no flush disc), half of it
DESCRIPTION_TOLERANCE_REL = {"ball_radius_m": 0.02, "electrode_radius_m": 0.5}


def description_tolerance(scene, protocol, overrides: dict | None = None, stated_keys=None) -> dict:
    """Each geometry unknown's prior standard deviation: :data:`DESCRIPTION_TOLERANCE`, the relative ones of
    :data:`DESCRIPTION_TOLERANCE_REL`, the frame's turn a quarter of the ring's spacing; none (``inf``) for what
    the ``[protocol]`` did not state (``stated_keys``: its keys as the user wrote them; a ball's radius taken by
    assumption) and for the balls' height; then ``overrides`` (a scene file's ``[tolerance]`` table: positive
    numbers, ``inf`` for no prior), checked against the unknowns' names.

    >>> from electrosense.meshes import Scene; from electrosense.meshes.cylinder_tank import CylinderTank
    >>> s = Scene(None, tank=CylinderTank(0.15, 0.3), electrodes=[DiscElectrode((0.15, 0.0, -0.05), 0.004)])
    >>> t = description_tolerance(s, {"ring": [1]}, {"water_depth_m": 0.01})
    >>> t["ring_radius_m"], t["water_depth_m"], t["electrode_radius_m"]
    (0.003, 0.01, 0.002)
    >>> description_tolerance(s, {"ring": [1]}, {"depth": 0.01})
    Traceback (most recent call last):
    ...
    ValueError: [tolerance] names depth, not an unknown of the scene fit (ring_radius_m, wall_slope, water_depth_m, ring_z_m, electrode_radius_m)
    """
    v = ring_state(scene, protocol)
    stated_keys = set(protocol if stated_keys is None else stated_keys)
    out = {n: DESCRIPTION_TOLERANCE.get(n, np.inf) for n in v}
    out.update({n: r * v[n] for n, r in DESCRIPTION_TOLERANCE_REL.items() if n in v})
    if "frame_rotation_rad" in v:
        out["frame_rotation_rad"] = 0.25 * 2 * np.pi / max(len(protocol.get("ring", [])), 1)
    if "ball_radius_m" in v and "ball_radius_m" not in stated_keys:
        out["ball_radius_m"] = np.inf
    out.update(checked_tolerance(overrides, out))
    return out


def checked_tolerance(table: dict | None, names=None) -> dict:
    """A scene file's ``[tolerance]`` table checked: each key one of ``names`` (default every geometry unknown of
    :data:`GEOMETRY_GROUPS`), each value a positive number (``inf``: no prior); a clear error otherwise.

    >>> checked_tolerance({"water_depth_m": 0.01})
    {'water_depth_m': 0.01}
    >>> checked_tolerance({"water_depth_m": -1})
    Traceback (most recent call last):
    ...
    ValueError: [tolerance] water_depth_m = -1: a standard deviation must be a positive number (inf: none)
    """
    names = [n for group in GEOMETRY_GROUPS.values() for n in group] if names is None else list(names)
    for n, val in (table or {}).items():
        if n not in names:
            raise ValueError(f"[tolerance] names {n}, not an unknown of the scene fit ({', '.join(names)})")
        if isinstance(val, bool) or not isinstance(val, (int, float)) or not val > 0:
            raise ValueError(f"[tolerance] {n} = {val!r}: a standard deviation must be a positive number (inf: none)")
    return {n: float(v) for n, v in (table or {}).items()}


def geometry_unknowns(scene, protocol, names=None, tolerance: dict | None = None) -> list[Unknown]:
    """The scene's unknowns (start: as stated) with bounds that keep the ring, the balls and the electrodes in the
    water; ``names`` picks some (default: all, the balls' only where the protocol places balls); ``tolerance``:
    each one's prior standard deviation about its stated value (:func:`description_tolerance`; default none).

    >>> from electrosense.meshes import Scene; from electrosense.meshes.cylinder_tank import CylinderTank
    >>> s = Scene(None, tank=CylinderTank(0.15, 0.3), electrodes=[DiscElectrode((0.15, 0.0, -0.05), 0.004)])
    >>> [u.name for u in geometry_unknowns(s, {"ring": [1]})]
    ['ring_radius_m', 'wall_slope', 'water_depth_m', 'ring_z_m', 'electrode_radius_m']
    """
    v = ring_state(scene, protocol)
    tank = scene.tank
    floor = tank.floor_z_m
    idx = _ring_discs(scene, protocol.get("ring", []))
    n = len(idx)
    R, a, z = v["ring_radius_m"], v["electrode_radius_m"], v["ring_z_m"]
    spacing = 2 * np.pi * R / max(n, 1)
    others = [e.centre_m[2] + e.radius_m for k, e in enumerate(scene.electrodes) if k not in set(idx)
              and isinstance(e, DiscElectrode) and e.centre_m[2] > floor + 1e-9]
    top = max([z + 2 * a] + others)
    us = [Unknown("ring_radius_m", R, 0.75 * R, 1.25 * R, 0.005, "m", "the tank's inner radius at the ring's height"),
          Unknown("wall_slope", v["wall_slope"], -0.25, 0.25, 0.02, "",
                  "dr/dz of the wall (a pail's taper: > 0 wider at the top)"),
          Unknown("water_depth_m", v["water_depth_m"], top - floor + 0.005, tank.height_m, 0.01, "m",
                  "the water depth"),
          Unknown("ring_z_m", z, floor + 2 * a + 0.002, v["water_depth_m"] + floor - 2 * a - 0.002, 0.005, "m",
                  "the ring's height (tank frame)"),
          Unknown("electrode_radius_m", a, 0.001, min(0.4 * spacing, 0.5 * (z - floor)), 0.001, "m",
                  "the ring electrodes' effective radius (the flush disc that draws the same current)")]
    if "ball_radius_m" in v:
        b = v["ball_radius_m"]
        us += [Unknown("ball_radius_m", b, 0.5 * b, 1.5 * b, 0.002, "m", "the balls' radius"),
               Unknown("ball_z_m", v["ball_z_m"], floor + 1.5 * b + 0.003, floor + v["water_depth_m"] - 1.5 * b - 0.003,
                       0.01, "m", "the balls' centres' height (tank frame)"),
               Unknown("frame_dx_m", 0.0, -0.3 * R, 0.3 * R, 0.004, "m",
                       "the set-ups' frame (where the balls are placed) shifted from the tank's axis, in x"),
               Unknown("frame_dy_m", 0.0, -0.3 * R, 0.3 * R, 0.004, "m", "the same in y"),
               Unknown("frame_rotation_rad", 0.0, -np.pi / n, np.pi / n, 0.03, "rad",
                       "the set-ups' frame turned about the axis from the ring's (counter-clockwise)")]
    tolerance = tolerance or {}
    us = [replace(u, prior=(u.value, tolerance[u.name])) if np.isfinite(tolerance.get(u.name, np.inf)) else u
          for u in us]
    return [u for u in us if names is None or u.name in names]


def scene_at(scene, protocol, values: dict, setup: str | None = None):
    """The scene with the geometry ``values`` (names of :func:`geometry_unknowns`; absent ones as stated) and the
    balls of ``setup`` (None: none). The wall's height and floor stay; the ring's electrodes keep their angles and
    their heights about the ring's mean; other wall discs follow the wall at their heights. The effective radius
    is every wall disc's that was stated as large as the ring's (the same hardware: a phantom's unused ring).

    Raises ValueError (naming what is wrong) when the scene is not a valid one.

    >>> from electrosense.meshes import Scene; from electrosense.meshes.cylinder_tank import CylinderTank
    >>> s = Scene(None, tank=CylinderTank(0.15, 0.3), electrodes=[DiscElectrode((0.15, 0.0, -0.05), 0.004)])
    >>> t = scene_at(s, {"ring": [1]}, {"ring_radius_m": 0.14, "wall_slope": 0.1, "ring_z_m": -0.04})
    >>> round(t.tank.floor_radius_m, 3), round(t.tank.radius_m, 3), np.round(t.electrodes[0].centre_m, 4).tolist()
    (0.129, 0.159, [0.14, 0.0, -0.04])
    """
    stated = ring_state(scene, protocol)
    v = {**stated, **{k: float(x) for k, x in values.items()}}
    tank = scene.tank
    floor, H = tank.floor_z_m, tank.height_m
    R, s, z = v["ring_radius_m"], v["wall_slope"], v["ring_z_m"]
    rf, rt = R - s * (z - floor), R + s * (floor + H - z)
    if rf <= 0 or rt <= 0:
        raise ValueError(f"the wall's radius would not be positive (floor {rf:.4g} m, top {rt:.4g} m)")
    new = replace(tank, radius_m=rt, floor_radius_m=rf, water_depth_m=min(v["water_depth_m"], H))
    idx = set(_ring_discs(scene, protocol.get("ring", [])))
    same = {k for k, e in enumerate(scene.electrodes) if isinstance(e, DiscElectrode)
            and abs(e.radius_m - stated["electrode_radius_m"]) < 1e-9}
    dz = z - stated["ring_z_m"]
    es = []
    for k, e in enumerate(scene.electrodes):
        on_wall = isinstance(e, DiscElectrode) and tank.on_wall(e.centre_m)
        if on_wall:
            ze = e.centre_m[2] + (dz if k in idx else 0.0)
            r, phi = float(new.radius_at(ze)), np.arctan2(e.centre_m[1], e.centre_m[0])
            e = replace(e, centre_m=(r * np.cos(phi), r * np.sin(phi), ze),
                        radius_m=v["electrode_radius_m"] if k in idx | same else e.radius_m)
        es.append(e)
    problems = disc_problems(new, es, first_label=scene.n_sensor_electrodes + 1)
    if problems:
        raise ValueError("; ".join(problems[:3]))
    objects = ()
    if setup is not None:
        b, zb = v["ball_radius_m"], v["ball_z_m"]
        surface = new.floor_z_m + new.water_depth_m
        if not (new.floor_z_m + b < zb < surface - b):
            raise ValueError(f"a ball of radius {b:.4g} m at z = {zb:.4g} m would not be in the water")
        c, sn = np.cos(v["frame_rotation_rad"]), np.sin(v["frame_rotation_rad"])
        xy = np.asarray(protocol[setup], float).reshape(-1, 2) @ np.array([[c, sn], [-sn, c]])
        objects = balls_at(xy + [v["frame_dx_m"], v["frame_dy_m"]], zb, b)
        for o in objects:
            x, y, _ = o.centre_m
            if np.hypot(x, y) + b >= new.radius_at(zb) - 0.002:
                raise ValueError(f"a ball at ({x:.3g}, {y:.3g}) m would touch the wall")
    return replace(scene, tank=new, electrodes=tuple(es), objects=objects)


def placeable_step(scene, protocol, start: dict, step: dict, setups=(None,), halvings: int = 6) -> tuple[float, str]:
    """The largest fraction (1, 1/2, ... 1/2**halvings, else 0) of a geometry step for which every set-up's scene is
    valid (:func:`scene_at`), and a note of what was shortened ('' when the whole step fits).

    >>> from electrosense.meshes import Scene; from electrosense.meshes.cylinder_tank import CylinderTank
    >>> s = Scene(None, tank=CylinderTank(0.15, 0.3), electrodes=[DiscElectrode((0.15, 0.0, -0.05), 0.004)])
    >>> f, note = placeable_step(s, {"ring": [1]}, {"ring_z_m": -0.05}, {"ring_z_m": -0.2})    # 20 cm down
    >>> f, note.split(" (")[0]
    (0.25, "step shortened to 0.25 of the fit's")
    """
    f, why = 1.0, ""
    for _ in range(halvings + 1):
        try:
            for su in setups:
                scene_at(scene, protocol, {k: start[k] + f * step.get(k, 0.0) for k in start}, su)
            return f, "" if f == 1.0 else f"step shortened to {f:g} of the fit's ({why})"
        except ValueError as exc:
            why = str(exc)
            f *= 0.5
    return 0.0, f"step refused ({why})"


def alternate_pair_folds(drive, ring) -> np.ndarray:
    """Fold of each row: 1 (held out) for drives at places 2, 3, 6, 7, ... of the ring, 0 for 0, 1, 4, 5, ...: half the
    drives held out, both parities in each half (a multiplexer's classes are all seen in training).

    >>> alternate_pair_folds(np.array([[1, 2], [2, 3], [3, 4], [4, 1]]), [1, 2, 3, 4]).tolist()
    [0, 0, 1, 1]
    """
    places = ring_pair_places(drive, ring)
    if places is None:
        raise ValueError("held-out drives need every drive pair on the ring")
    return (places // 2) % 2


def gauge_rows(log_gains, tolerance: float) -> np.ndarray:
    """The residual row that holds a set of log gains' mean at zero (to ``tolerance``)."""
    return np.atleast_1d(np.sum(log_gains) / tolerance)


#: the classes of (drive pair, measurement pair) by the parity of their places on the ring, as ``cls`` numbers them
PARITY_CLASSES = ("even_even", "even_odd", "odd_even", "odd_odd")

#: the largest common-mode fraction (in phase or in quadrature) the fit considers: 1 is no rejection at all. At
#: 0.2, the bound of before, a blind file of the second Ottawa file's layout with 0.4 in quadrature (the empty
#: tank 0.098 off, the size of that file's gap) was clipped there, and its fits left the held-out balls 0.55-0.59
#: off where the diagnosis, unbounded, found 0.399
COMMON_MODE_BOUND = 1.0


def instrument_unknowns(n_channels: int, ground: bool, parity: bool = True,
                        typical_ohm: float | None = None) -> list[Unknown]:
    """The measurement system's unknowns: scale, multiplexer classes (a gain each and, given the rows' typical
    transfer impedance ``typical_ohm``, a crosstalk each), channel gains, common mode, ground current.

    The in-phase common mode against a ground electrode and the share of the drive current through that
    electrode change the readings alike (correlation 0.99998 on the Ottawa pail): with a ground, only the latter.
    A class's crosstalk is a fixed voltage per unit current (ohm at the nominal conductivity) added to each
    reading of the class: relative to the reading it matters most on the far side, where ``|Z|`` is smallest.

    >>> [u.name for u in instrument_unknowns(2, ground=False)]  # doctest: +NORMALIZE_WHITESPACE
    ['log_scale', 'mux_even_odd', 'mux_odd_even', 'mux_odd_odd', 'channel_gain_1', 'channel_gain_2',
     'common_mode_in_phase', 'common_mode_quadrature']
    """
    us = [Unknown("log_scale", 0.0, -30, 30, 0.05, "", "log of the reading over the BEM's |Z| at the nominal sigma")]
    if parity:
        us += [Unknown(f"mux_{c}", 0.0, -1.0, 1.0, 0.02, "log", f"gain of the {c.replace('_', '-')} class of (drive "
                       "pair, measurement pair) by their places' parity, over the even-even class")
               for c in PARITY_CLASSES[1:]]
        if typical_ohm:
            us += [Unknown(f"crosstalk_{c}", 0.0, -10 * typical_ohm, 10 * typical_ohm, 0.01 * typical_ohm, "ohm",
                           f"fixed voltage per unit current added to each reading of the {c.replace('_', '-')} "
                           "class (a multiplexer group's crosstalk), at the nominal conductivity")
                   for c in PARITY_CLASSES]
    us += [Unknown(f"channel_gain_{k + 1}", 0.0, -1.0, 1.0, 0.02, "log",
                   f"measurement channel {k + 1}'s gain (mean 0 over the odd and over the even channels)") for k in range(n_channels)]
    if not ground:       # against a ground electrode, the in-phase part reads as the current through it
        us.append(Unknown("common_mode_in_phase", 0.0, -COMMON_MODE_BOUND, COMMON_MODE_BOUND, 1e-3, "",
                          "in-phase fraction of V_cm read"))
    us += [Unknown("common_mode_quadrature", 1e-4, -COMMON_MODE_BOUND, COMMON_MODE_BOUND, 1e-3, "",
                   "quadrature fraction of V_cm read (its sign is not determined)")]
    if ground:
        us.append(Unknown("ground_fraction", 0.0, -0.5, 0.5, 0.01, "",
                          "fraction of the drive current returning through the ground electrode"))
    return us


@dataclass
class SetupSurrogate:
    """``log |Z|`` of one set-up's rows, linear in the geometry about an anchor; signs, common-mode and ground rows
    (ohm per ampere) at the anchor."""

    names: list
    anchor: np.ndarray
    log_Z: np.ndarray
    D: np.ndarray
    sign: np.ndarray
    V_cm: np.ndarray
    Z_ground: np.ndarray | None

    def log_abs(self, theta) -> np.ndarray:
        return self.log_Z + self.D @ (np.asarray(theta, float) - self.anchor)

    def secant(self, theta, log_Z, scale) -> np.ndarray:
        """The derivatives given Broyden's update from a solve at ``theta`` (exact along the step from the anchor;
        ``scale``: the unknowns' typical steps, the metric of the update)."""
        dt = (np.asarray(theta, float) - self.anchor) / scale
        nrm = float(dt @ dt)
        if nrm == 0:
            return self.D
        return self.D + np.outer(log_Z - self.log_Z - self.D @ (dt * scale), dt / scale) / nrm

    def moved(self, theta, log_Z, sign, V_cm, Z_ground, scale) -> "SetupSurrogate":
        """The surrogate anchored at ``theta`` (solved there: ``log_Z``...) with the secant's derivatives."""
        return SetupSurrogate(self.names, np.asarray(theta, float), log_Z, self.secant(theta, log_Z, scale), sign,
                              V_cm, Z_ground)

    def learned(self, theta, log_Z, scale) -> "SetupSurrogate":
        """The same anchor, the derivatives given the secant to a solve at ``theta`` (a step not taken)."""
        return replace(self, D=self.secant(theta, log_Z, scale))


def _rows(K, table, reference, ground):
    Z, Vcm, _ = common_mode_rows(K, table.drive, table.measure, reference)
    Zg = None
    if ground is not None:
        Zg = model_transfer_ohm(K, np.c_[table.drive[:, 0], np.full(len(table.drive), ground)], table.measure)
    return Z, Vcm, Zg


@dataclass
class _Problem:
    scene: object
    protocol: dict
    sigma: float
    bem_options: dict
    table: object
    reference: list
    ground: int | None
    solves: list
    focus_m: np.ndarray | None = None

    def solve(self, values: dict, setup, bem_options: dict | None = None):
        """The rows of the scene at ``values`` with the balls of ``setup``; every set-up's tank is meshed alike
        (graded towards ``focus_m``, not towards its own balls), so that a ball's difference signal is not
        the difference of two tank meshes."""
        t0 = time.perf_counter()
        opts = self.bem_options if bem_options is None else bem_options
        if self.focus_m is not None:
            opts = {**opts, "tank_focus_m": self.focus_m}
        sol = solve_scene(scene_at(self.scene, self.protocol, values, setup), self.sigma, **opts)
        self.solves.append(time.perf_counter() - t0)
        return _rows(sol.conductance.K_S, self.table, self.reference, self.ground)


def discretisation_error(problem: _Problem, values: dict, setup, refine: float = REFINE) -> tuple:
    """The BEM's own error at the fit's mesh, row by row: ``log |Z|`` (and, with ``setup``, its difference signal)
    against the same scene on a mesh whose lengths (the tank's far edge, the electrodes' rim edge, the edge's growth
    from a rim: :func:`~electrosense.validation.comparison.study_mesh.refined_options`) are ``refine`` times the
    fit's, over ``1 - refine ** BEM_ORDER`` (Richardson), the mean of ``log |Z|`` removed (a scale, which the
    instrument's scale takes). Two solves per set-up (the reference and ``setup``).
    Returns the two (R,) error vectors (the signal's None without ``setup``).
    """
    fine = refined_options(problem.bem_options, problem.scene.tank, refine)
    factor = 1.0 / (1.0 - refine ** BEM_ORDER)
    z = [problem.solve(values, None, o)[0] for o in (None, fine)]
    d = np.log(np.abs(z[0])) - np.log(np.abs(z[1]))
    if setup is None:
        return factor * (d - d.mean()), None
    b = [problem.solve(values, setup, o)[0] for o in (None, fine)]
    sig = [np.abs(bb) / np.abs(zz) - 1 for bb, zz in zip(b, z)]
    return factor * (d - d.mean()), factor * (sig[0] - sig[1])


def _surrogate(problem: _Problem, unknowns, values: dict, setup, log=print) -> SetupSurrogate:
    """Solve at ``values`` and one forward difference per unknown (towards the inside of its bounds)."""
    names = [u.name for u in unknowns]
    Z, Vcm, Zg = problem.solve(values, setup)
    base = np.log(np.abs(Z))
    D = np.zeros((len(Z), len(unknowns)))
    for k, u in enumerate(unknowns):
        h = u.step if values[u.name] + u.step <= u.upper else -u.step
        try:
            Zk, _, _ = problem.solve({**values, u.name: values[u.name] + h}, setup)
        except ValueError:
            h = -h
            Zk, _, _ = problem.solve({**values, u.name: values[u.name] + h}, setup)
        D[:, k] = (np.log(np.abs(Zk)) - base) / h
    log(f"  surrogate of {setup or 'the reference'}: {1 + len(unknowns)} solves")
    return SetupSurrogate(names, np.array([values[n] for n in names]), base, D, np.sign(Z), Vcm, Zg)


@dataclass
class _Data:
    """The measured side: the reference's magnitudes, folds, classes and channels; each ball set-up's signal."""

    Z_ref: np.ndarray
    train: np.ndarray
    cls: np.ndarray
    channel: np.ndarray
    n_channels: int
    signals: dict
    floor_ref: float
    floors: dict
    bem_log_Z: np.ndarray | None = None
    bem_signal: np.ndarray | None = None


def _reading(Z, Vcm, Zg, inst: dict, cls, channel, Z_anchor_abs=None):
    """log of the instrument's reading of signed rows ``Z`` (common mode ``Vcm``, ground rows ``Zg``)."""
    if Zg is not None and "ground_fraction" in inst:
        f = inst["ground_fraction"]
        Z = (1 - f) * Z + f * Zg * (1.0 if Z_anchor_abs is None else np.abs(Z) / Z_anchor_abs)
    cr, ci = inst.get("common_mode_in_phase", 0.0), inst.get("common_mode_quadrature", 0.0)
    magnitude = np.hypot(Z + cr * Vcm, ci * Vcm)
    crosstalk = np.array([inst.get(f"crosstalk_{c}", 0.0) for c in PARITY_CLASSES])[cls]
    if np.any(crosstalk):           # a reading cannot go below zero: held at a thousandth of the magnitude
        magnitude = np.maximum(magnitude + crosstalk, 1e-3 * magnitude)
    out = np.log(magnitude) + inst.get("log_scale", 0.0)
    mux = np.array([0.0] + [inst.get(f"mux_{c}", 0.0) for c in PARITY_CLASSES[1:]])
    gains = np.array([inst.get(f"channel_gain_{k + 1}", 0.0) for k in range(int(channel.max()) + 1)])
    return out + mux[cls] + gains[channel]


def reference_outliers(model_signals: dict, data, threshold: float = 8.0) -> list[int]:
    """Rows where every ball set-up's measured signal departs from the model's by more than ``threshold`` of its
    floor, all with one sign: the reference's own value is off (it divides every signal), not the balls'.

    >>> d = _Data(np.ones(3), None, None, None, 0, {"A": np.array([0.0, 0.1, 0.0]), "B": np.array([0.0, 0.2, 0.0])},
    ...           0.01, {"A": 0.01, "B": 0.01})
    >>> reference_outliers({"A": np.zeros(3), "B": np.zeros(3)}, d)
    [1]
    """
    if len(model_signals) < 2:
        return []
    z = np.stack([(data.signals[k] - model_signals[k]) / data.floors[k] for k in model_signals])
    same_sign = np.all(z > 0, axis=0) | np.all(z < 0, axis=0)
    return np.flatnonzero(same_sign & (np.abs(z).min(axis=0) > threshold)).tolist()


def _rms(x) -> float:
    x = np.asarray(x, float)
    return float(np.sqrt(np.mean(x ** 2))) if x.size else float("nan")


def _amplitude(d_model, d_meas) -> float:
    return float(d_model @ d_meas / (d_model @ d_model)) if np.any(d_model) else float("nan")


def _signal_scores(d_model, d_meas) -> dict:
    """A set-up's signal error RMS over its RMS, the measured/model amplitude, and the amplitude on the quarter of
    rows where the model's signal is largest (the electrodes nearest a ball) and on the rest: where they differ,
    the misfit is no scale of the signal.

    >>> s = _signal_scores(np.array([4.0, 1.0, 1.0, 0.5]), np.array([8.0, 1.0, 1.0, 0.5]))
    >>> s["amplitude_largest_quarter"], s["amplitude_other_rows"]
    (2.0, 1.0)
    """
    d_model, d_meas = np.asarray(d_model, float), np.asarray(d_meas, float)
    big = np.abs(d_model) >= np.quantile(np.abs(d_model), 0.75)
    return {"rms_rel": _rms(d_model - d_meas) / _rms(d_meas), "measured_over_model_amplitude": _amplitude(d_model, d_meas),
            "amplitude_largest_quarter": _amplitude(d_model[big], d_meas[big]),
            "amplitude_other_rows": _amplitude(d_model[~big], d_meas[~big])}


class _Model:
    """Residuals of every unknown's vector on the surrogates of the reference and the fitted set-up."""

    def __init__(self, data: _Data, unknowns, n_geometry, ref: SetupSurrogate, ball: SetupSurrogate | None,
                 fit_setup, ref_block: bool = True):
        self.data, self.unknowns, self.nG, self.ref_block = data, unknowns, n_geometry, ref_block
        self.names = [u.name for u in unknowns]
        self.ref, self.ball, self.fit_setup = ref, ball, fit_setup
        self.steps = np.array([u.step for u in unknowns])

    def inst(self, x) -> dict:
        return dict(zip(self.names[self.nG:], x[self.nG:]))

    def posterior_rows(self, x) -> np.ndarray:
        """:meth:`residual` and the geometry's prior rows (:func:`prior_rows`): what the fit minimises."""
        return np.concatenate([self.residual(x), prior_rows(self.unknowns, x)])

    def log_reading(self, sur: SetupSurrogate, x):
        la = sur.log_abs(x[:self.nG])
        return _reading(sur.sign * np.exp(la), sur.V_cm, sur.Z_ground, self.inst(x), self.data.cls,
                        self.data.channel, np.exp(sur.log_Z))

    def residual(self, x):
        d = self.data
        lr = self.log_reading(self.ref, x)
        r = [(lr - np.log(d.Z_ref))[d.train] / d.floor_ref] if self.ref_block else []
        if self.ball is not None:
            sig = np.exp(self.log_reading(self.ball, x) - lr) - 1
            r.append((sig - d.signals[self.fit_setup]) / d.floors[self.fit_setup])
        gains = np.array([x[i] for i, n in enumerate(self.names) if n.startswith("channel_gain_")])
        if gains.size:      # the mean over the odd and over the even channels: the scale's and the classes'
            r += [gauge_rows(gains[0::2], 1e-4), gauge_rows(gains[1::2], 1e-4)]
        return np.concatenate(r)

    def bem_rows(self) -> np.ndarray:
        """The BEM's error (:func:`discretisation_error`) as rows of :meth:`residual`: how far the model's rows
        are off by its mesh alone."""
        d = self.data
        r = [d.bem_log_Z[d.train] / d.floor_ref] if self.ref_block else []
        if self.ball is not None:
            r.append(d.bem_signal / d.floors[self.fit_setup])
        n_gains = sum(n.startswith("channel_gain_") for n in self.names)
        return np.concatenate(r + [np.zeros(2 if n_gains else 0)])

    def jacobian(self, x):
        r0 = self.residual(x)
        J = np.empty((len(r0), len(x)))
        for k in range(len(x)):
            h = 1e-4 * self.steps[k]
            xp, xm = x.copy(), x.copy()
            xp[k] += h
            xm[k] -= h
            J[:, k] = (self.residual(xp) - self.residual(xm)) / (2 * h)
        return J


def measured_data(log, protocol) -> _Data:
    """The reference set-up's magnitudes and rows, and every ball set-up's difference signal with its floor."""
    from electrosense.validation.comparison.transfer import measurement_noise, pair_parity_classes

    ref = str(protocol.get("reference", log.setups[0]))
    t = setup_table(log, ref)
    ring = [int(e) for e in protocol.get("ring", [])]
    dp, mp = ring_pair_places(t.drive, ring), ring_pair_places(t.measure, ring)
    if dp is None or mp is None:
        raise ValueError("the scene fit needs every drive and measurement pair on the [protocol] ring")
    Z = np.abs(t.Z_ohm)
    signals, floors = {}, {}
    for su in log.setups:
        if su == ref or su not in protocol:
            continue
        o = setup_table(log, su)
        if not (np.array_equal(o.drive, t.drive) and np.array_equal(o.measure, t.measure)):
            raise ValueError(f"set-up {su} does not have the reference's measurements")
        signals[su] = np.abs(o.Z_ohm) / Z - 1
        floors[su] = signal_floor(t.drive, t.measure, Z, np.abs(o.Z_ohm))
    # the reciprocity floor, less an instrument's part that breaks reciprocity
    floor = measurement_noise(t.drive, t.measure, t.Z_ohm, ring)["fit_noise_rel"]
    return _Data(Z, alternate_pair_folds(t.drive, ring) == 0, pair_parity_classes(t.drive, t.measure, ring), mp,
                 len(ring), signals, float(floor), floors)


def fit_tank_scene(log, scene, sigma_S_per_m: float, bem_options: dict, protocol: dict, fit_setup: str | None = None,
                   max_iterations: int = 4, geometry=None, tolerance: dict | None = None, report=print) -> dict:
    """The scene's and the instrument's unknowns fitted on the reference set-up's training drives and one ball
    set-up (``fit_setup``; default the first the protocol places), scored on the held-out drives and the other
    ball set-ups, each solved on the BEM at the fitted scene. Two ways (``fits``):

    * ``joint``: every unknown on both blocks at once;
    * ``staged``: the geometry that the balls' signals see (the tank's radius and slope, the balls' radius,
      height and frame) from the fitted set-up's signal alone (no instrument gain enters it), the rest of the
      scene as stated; then the instrument on both blocks, that scene held.

    Returns the metrics: per fit ``fitted`` (every unknown with its standard error and unit), ``not_separable``,
    ``correlated``, ``at_bound``, ``scores`` (``empty_heldout_rms_rel``, per ball set-up its signal's RMS error
    over its RMS, the floor, the amplitude), ``iterations``; ``stated`` and ``what_each_explains`` (the
    instrument's unknowns added one group at a time at the stated scene, then each fit); ``solves``.
    ``geometry``: the names of the geometry unknowns to fit (default all of :func:`geometry_unknowns`; the others
    stay as stated). ``tolerance``: the scene file's ``[tolerance]`` table (:func:`description_tolerance`): the
    description is a measurement too, and a fit maximises the posterior with each stated value a Gaussian prior
    (a scene scaled as a whole, its balls shifted to the same places relative to the wall, fits one ball set-up
    and an empty tank alike; only the description tells them apart).
    """
    stated_keys = set(protocol)
    t_start = time.perf_counter()
    data = measured_data(log, protocol)
    ball_setups = list(data.signals)
    if fit_setup is None and ball_setups:
        fit_setup = ball_setups[0]
    if fit_setup is not None and fit_setup not in data.signals:
        raise ValueError(f"set-up {fit_setup} is not a ball set-up of the log and the protocol")
    ring = [int(e) for e in protocol.get("ring", [])]
    floating = [int(e) for e in protocol.get("floating", [])]
    reference = instrument_reference(scene.n_electrodes, ring, floating)
    grounds = [e for e in range(1, scene.n_electrodes + 1) if e not in set(ring) | set(floating)]
    ground = grounds[0] if len(grounds) == 1 else None
    table = setup_table(log, str(protocol.get("reference", log.setups[0])))
    if ball_setups and "ball_radius_m" not in protocol:      # the comparison's assumption (said in its metrics)
        protocol = {**protocol, "ball_radius_m": stated_balls(scene, protocol)["radius_m"]}
    stated = ring_state(scene, protocol)
    focus = objects_focus_m([o for su in ball_setups
                             for o in balls_at(protocol[su], stated["ball_z_m"], stated["ball_radius_m"])])
    problem = _Problem(scene, protocol, sigma_S_per_m, bem_options, table, reference, ground, [], focus)
    tolerances = description_tolerance(scene, protocol, tolerance, stated_keys)
    geo = geometry_unknowns(scene, protocol, geometry, tolerances)
    if fit_setup is None:
        geo = [u for u in geo if u.name not in BALL_ONLY]
    gnames = [u.name for u in geo]
    theta0 = {u.name: u.value for u in geo}

    # surrogates at the stated scene: the reference (no derivative for the balls), the fitted set-up
    ref_unknowns = [u for u in geo if u.name not in BALL_ONLY]
    s_ref = _surrogate(problem, ref_unknowns, theta0, None, report)
    D = np.zeros((len(s_ref.log_Z), len(geo)))
    D[:, [gnames.index(u.name) for u in ref_unknowns]] = s_ref.D
    s_ref = replace(s_ref, names=gnames, anchor=np.array([theta0[n] for n in gnames]), D=D)
    s_ball = _surrogate(problem, geo, theta0, fit_setup, report) if fit_setup else None
    inst = instrument_unknowns(data.n_channels, ground is not None, typical_ohm=float(np.exp(np.median(s_ref.log_Z))))
    fit = _Fit(problem, data, geo + inst, len(geo), fit_setup, report)
    data.bem_log_Z, data.bem_signal = discretisation_error(problem, theta0, fit_setup)
    bem_ref, bem_sig = _rms(data.bem_log_Z), _rms(data.bem_signal) if fit_setup is not None else float("nan")
    data.floor_ref = float(np.hypot(data.floor_ref, bem_ref))
    if fit_setup is not None:
        data.floors = {k: float(np.hypot(v, bem_sig)) for k, v in data.floors.items()}
    out = {"fit_setup": fit_setup, "heldout_setups": [s for s in ball_setups if s != fit_setup],
           "stated": theta0, "tolerance": {n: t for n, t in tolerances.items() if np.isfinite(t)}, "noise": {
               "reference_per_measurement_rel": data.floor_ref, "signal_floor_rel": dict(data.floors),
               "bem_discretisation_log_Z": bem_ref, "bem_discretisation_signal": bem_sig,
               "model": "independent errors: the reference's log|Z| of one standard deviation (its reciprocity "
                        "floor and the BEM's discretisation error against a finer mesh, in quadrature), each ball "
                        "signal's of its own floor (its reciprocity, and the BEM's); the fit's scatter scales both "
                        "(noise_rms); rows beyond 3 times the typical misfit (the floor, or the plain fit's "
                        "scatter where larger) weigh less (soft L1); each stated length a Gaussian prior of "
                        "the description's tolerance (`tolerance`, one standard deviation)"}}
    explains = _instrument_models(fit, s_ref, s_ball, theta0, ball_setups)

    fits, optional = {}, [u.name for u in inst if u.name.startswith(OPTIONAL_INSTRUMENT)]
    out["optional_instrument"] = {}
    ok, held, placed = fit.placed_chord(s_ref, s_ball, optional, True, max_iterations)
    ok, out["optional_instrument"]["joint"] = _with_optional(fit, ok, optional, held, max_iterations)
    fits["joint"] = {**fit.result(*ok, ball_setups), "held_at_stated": held, "unplaced": placed}
    if fit_setup is not None:
        seen = [n for n in gnames if n in GEOMETRY_GROUPS["tank"][:2] or n in BALL_ONLY]
        inst_names = [u.name for u in inst]
        a, held, placed = fit.placed_chord(s_ref, s_ball, inst_names + [n for n in gnames if n not in seen], False,
                                           max_iterations)
        b = fit.chord(a[2], a[3], fixed=gnames + optional, ref_block=True, max_iterations=0)
        b, out["optional_instrument"]["staged"] = _with_optional(fit, b, optional, gnames, 0)
        fits["staged"] = {**fit.result(*b, ball_setups), "held_at_stated": held, "unplaced": placed}
        shift = bem_shift(a[0], a[1])       # the geometry's uncertainty is that of the first stage
        for k, n in enumerate(gnames):
            if np.isfinite(a[1].se[k]):
                fits["staged"]["fitted"][n].update(se=float(a[1].se[k]), se_bem=float(shift[k]),
                                                   se_total=float(np.hypot(a[1].se[k], shift[k])))
                if "prior_sd" in fits["staged"]["fitted"][n]:
                    fits["staged"]["fitted"][n]["set_by_prior"] = set_by_prior(
                        a[1].se[k], fits["staged"]["fitted"][n]["prior_sd"], a[1].noise_rms)
        fits["staged"]["iterations"] = a[4]
        fits["staged"]["converged"] = a[5]
    for name, f in fits.items():
        left_out = 0 if out["optional_instrument"][name].get("kept", True) else len(optional)
        explains.append({"model": f"scene, {name}", "n_parameters": len(fit.unknowns) - left_out,
                         "empty_heldout_rms_rel": f["scores"]["empty_heldout_rms_rel"],
                         "setups_rms_rel": {k: v["rms_rel"] for k, v in f["scores"]["setups"].items()}})
    out["fits"] = fits
    out["what_each_explains"] = explains
    out["solves"] = {"count": len(problem.solves), "seconds": float(np.sum(problem.solves))}
    out["wall_s"] = time.perf_counter() - t_start
    return out


class _Fit:
    """The fits of one problem: chord Gauss-Newton on the surrogates, and scores on the BEM."""

    def __init__(self, problem, data, unknowns, nG, fit_setup, report):
        self.problem, self.data, self.unknowns, self.nG = problem, data, unknowns, nG
        self.fit_setup, self.report = fit_setup, report
        self.gnames = [u.name for u in unknowns[:nG]]
        self.names = [u.name for u in unknowns]

    def once(self, ref, ball, fixed=(), ref_block=True, start=None, radius=TRUST):
        """The fit on the surrogates, the geometry kept within ``radius`` typical steps of the anchor."""
        x0 = np.r_[ref.anchor, [u.value for u in self.unknowns[self.nG:]]] if start is None else start
        us = [replace(u, value=float(np.clip(v, max(u.lower, a - radius * u.step), min(u.upper, a + radius * u.step))),
                      lower=max(u.lower, a - radius * u.step), upper=min(u.upper, a + radius * u.step))
              for u, v, a in zip(self.unknowns[:self.nG], x0, ref.anchor)]
        us += [replace(u, value=float(v)) for u, v in zip(self.unknowns[self.nG:], x0[self.nG:])]
        m = _Model(self.data, us, self.nG, ref, ball, self.fit_setup, ref_block)
        plain = fit_unknowns(m.residual, m.jacobian, us, max_nfev=200, fixed=fixed)
        us = [replace(u, value=float(v)) for u, v in zip(us, plain.x)]
        # a model that misses every row by a few floors is not made of outliers: the loss's scale is the misfit's
        f_scale = F_SCALE * max(plain.noise_rms, 1.0)
        return m, fit_unknowns(m.residual, m.jacobian, us, max_nfev=200, fixed=fixed, loss=LOSS, f_scale=f_scale)

    def chord(self, s_ref, s_ball, fixed, ref_block, max_iterations):
        """Gauss-Newton on the surrogates with a trust region (Levenberg-Marquardt's rule, Broyden's secant for the
        derivatives): fit within ``radius`` typical steps of the anchor, solve the scene there (shortened where it
        would not be placeable), keep the step if the cost fell (:meth:`_Model.posterior_rows`: the data's rows and
        the geometry's priors; the surrogate moved there), else learn from it and
        halve the radius; until the free geometry's step is below half its standard error. Returns (model, fit,
        surrogates, iterations, converged). Not converged: the geometry stays at the anchor (the last scene solved
        that lowered the cost), the rest fitted there."""
        gn, nG, problem = self.gnames, self.nG, self.problem
        free = np.array([n not in set(fixed) for n in gn])
        scale = np.array([u.step for u in self.unknowns[:nG]])
        inst0 = np.array([u.value for u in self.unknowns[nG:]])
        radius = TRUST

        def at_anchor(ref, ball, start_inst):
            return self.once(ref, ball, list(fixed) + gn, ref_block, np.r_[ref.anchor, start_inst])

        model, sf_anchor = at_anchor(s_ref, s_ball, inst0)
        iterations, converged = [], False
        for it in range(max_iterations + 1):
            model, sf = self.once(s_ref, s_ball, fixed, ref_block, np.r_[s_ref.anchor, sf_anchor.x[nG:]], radius)
            step = np.where(free, sf.x[:nG] - s_ref.anchor, 0.0)
            se = np.where(np.isfinite(sf.se[:nG]), sf.se[:nG], np.inf)
            # the posterior's cost (the data's rows and the geometry's priors) at the anchor and at the fit's point
            cost_anchor, cost_predicted = _cost(model, sf_anchor.x), _cost(model, sf.x)
            iterations.append({"geometry": {n: round(float(v), 6) for n, v, f in zip(gn, sf.x[:nG], free) if f},
                               "cost_at_anchor": cost_anchor, "cost_predicted": cost_predicted,
                               "trust_radius_steps": radius})
            if np.all(np.abs(step) <= np.maximum(0.5 * se, 1e-3 * scale)):
                converged = True
                break
            if it == max_iterations:
                break
            f, note = placeable_step(problem.scene, problem.protocol, dict(zip(gn, s_ref.anchor)),
                                     dict(zip(gn, step)), (None, *self.data.signals))
            if note:
                iterations[-1]["note"] = note
            if f == 0:
                break
            theta = s_ref.anchor + f * step
            values = dict(zip(gn, theta))
            Z, Vcm, Zg = problem.solve(values, None)
            iterations[-1]["surrogate_error_rel"] = _rms(np.log(np.abs(Z)) - s_ref.log_abs(theta))
            new_ref = s_ref.moved(theta, np.log(np.abs(Z)), np.sign(Z), Vcm, Zg, scale)
            new_ball = None
            if s_ball is not None:
                Zb, Vb, Zgb = problem.solve(values, self.fit_setup)
                new_ball = s_ball.moved(theta, np.log(np.abs(Zb)), np.sign(Zb), Vb, Zgb, scale)
            m_new, sf_new = at_anchor(new_ref, new_ball, sf.x[nG:])
            cost_new = _cost(m_new, sf_new.x)
            iterations[-1]["cost_solved"] = cost_new
            gain = (cost_anchor - cost_new) / max(cost_anchor - cost_predicted, 1e-300)
            if cost_new < cost_anchor:          # taken
                s_ref, s_ball, sf_anchor, model = new_ref, new_ball, sf_new, m_new
                if gain > 0.75 and f == 1:
                    radius = min(2 * radius, 4 * TRUST)
                elif gain < 0.25:
                    radius /= 2
            else:                               # not taken: the derivatives learn from it, the region shrinks
                s_ref = s_ref.learned(theta, new_ref.log_Z, scale)
                if s_ball is not None:
                    s_ball = s_ball.learned(theta, new_ball.log_Z, scale)
                radius /= 4
            self.report(f"  iteration {it + 1}: {'moved to' if cost_new < cost_anchor else 'tried'} "
                        + ", ".join(f"{n} {v:.4g}" for n, v, fr in zip(gn, theta, free) if fr)
                        + f" (cost {cost_anchor:.4g} -> {cost_new:.4g}, predicted {cost_predicted:.4g})")
        if not converged:
            free_se = sf.se[:nG].copy()
            model, sf = model, sf_anchor
            sf.se[:nG] = free_se
        return model, sf, s_ref, s_ball, iterations, converged

    def placed_chord(self, s_ref, s_ball, fixed, ref_block, max_iterations):
        """:meth:`chord` from the stated scene, and again with the geometry the data do not place (:func:`unplaced`)
        held at its stated value; the fit of lower :func:`bic` (of :meth:`_Model.posterior_rows`) is kept (an
        unknown the data leave anywhere within its bounds would otherwise stay where the search left it, and the
        set-ups the fit never saw pay for it;
        a pair that trades off, each unplaced alone, may still be placed together, and then the free fit wins).
        Returns (the chord's result, the names held, what was compared)."""
        free = self.chord(s_ref, s_ball, fixed=list(fixed), ref_block=ref_block, max_iterations=max_iterations)
        loose = [n for n in unplaced(free[1].se[:self.nG], self.unknowns[:self.nG]) if n not in set(fixed)]
        if not loose:
            return free, [], {}
        held = self.chord(s_ref, s_ball, fixed=list(fixed) + loose, ref_block=ref_block,
                          max_iterations=max_iterations)
        n_free = len([n for n in self.names if n not in set(fixed)])
        b_free = bic(free[0].posterior_rows(free[1].x), n_free)
        b_held = bic(held[0].posterior_rows(held[1].x), n_free - len(loose))
        kept = b_held <= b_free
        self.report(f"  {', '.join(loose)} not placed by the data: held at their stated values the BIC is "
                    f"{b_held:.1f}, free {b_free:.1f}: {'held' if kept else 'left free'}")
        return (held if kept else free), (loose if kept else []), {"unplaced": loose, "bic_free": b_free,
                                                                   "bic_held": b_held, "held": bool(kept)}

    def result(self, model, sf, s_ref, s_ball, iterations, converged, ball_setups) -> dict:
        """Scores of a fit: the reference's held-out drives, every ball set-up solved at the fitted scene."""
        data, x = self.data, sf.x
        # the fit's last move on the surrogate, from the last scene solved, kept placeable (shortened and said)
        f, note = placeable_step(self.problem.scene, self.problem.protocol, dict(zip(self.gnames, s_ref.anchor)),
                                 dict(zip(self.gnames, x[:self.nG] - s_ref.anchor)), (None, *ball_setups))
        theta = s_ref.anchor + f * (x[:self.nG] - s_ref.anchor)
        values, inst = dict(zip(self.gnames, theta)), model.inst(x)
        # every row of one scene from one kind of solve: a signal is a ratio of two set-ups' rows a few per cent
        # apart, and a surrogate's error on one of them (or two meshes' difference) would be all of its error
        if np.allclose(theta, s_ref.anchor):
            lr_ref = model.log_reading(s_ref, np.r_[theta, x[self.nG:]])
        else:
            lr_ref = _reading(*self.problem.solve(values, None), inst, data.cls, data.channel)
        rel = np.exp(lr_ref - np.log(data.Z_ref)) - 1
        scores = {"empty_heldout_rms_rel": _rms(rel[~data.train]), "empty_train_rms_rel": _rms(rel[data.train]),
                  "setups": {}, **({"solved_at": note} if note else {})}
        signals = {}
        for su in ball_setups:
            if su == self.fit_setup and s_ball is not None and np.allclose(s_ball.anchor, theta) \
                    and np.allclose(theta, s_ref.anchor):
                signals[su] = np.exp(model.log_reading(s_ball, np.r_[theta, x[self.nG:]]) - lr_ref) - 1
            else:
                signals[su] = np.exp(_reading(*self.problem.solve(values, su), inst, data.cls, data.channel)
                                     - lr_ref) - 1
        odd = reference_outliers(signals, data)
        keep = np.ones(len(data.Z_ref), bool)
        keep[odd] = False
        for su in ball_setups:
            scores["setups"][su] = {**_signal_scores(signals[su], data.signals[su]),
                                    "held_out": su != self.fit_setup,
                                    "rms_rel_without_outlying_rows": _signal_scores(signals[su][keep],
                                                                                    data.signals[su][keep])["rms_rel"],
                                    "floor_rel": data.floors[su] / _rms(data.signals[su])}
        t = self.problem.table
        scores["outlying_reference_rows"] = [
            {"drive": t.drive[r].tolist(), "measure": t.measure[r].tolist(), "signal_minus_model_over_floor": {
                su: round(float((data.signals[su][r] - signals[su][r]) / data.floors[su]), 1) for su in ball_setups}}
            for r in odd]
        units = {u.name: u.unit for u in self.unknowns}
        fitted = sf.table(units)
        for u, se in zip(self.unknowns, sf.se):      # a prior of geometry held in the fit's last stage, too
            if u.prior is not None and "prior_sd" not in fitted[u.name]:
                fitted[u.name].update(prior_sd=u.prior[1], set_by_prior=set_by_prior(se, u.prior[1], sf.noise_rms))
        for name, shift in zip(self.names, bem_shift(model, sf)):
            if np.isfinite(shift):
                se = fitted[name]["se"]
                fitted[name].update(se_bem=float(shift), se_total=float(np.hypot(se, shift)))
        return {"converged": converged, "scores": scores, "fitted": fitted,
                "not_separable": sf.not_separable, "correlated": sf.correlated, "at_bound": sf.at_bound,
                "noise_rms": sf.noise_rms, "iterations": iterations}


def _cost(model: _Model, x) -> float:
    r = model.posterior_rows(x)
    return float(r @ r)


def bem_shift(model: _Model, sf) -> np.ndarray:
    """How far each determined unknown moves when the data move by the BEM's own error (:meth:`_Model.bem_rows`),
    to first order (the linearised fit); NaN for unknowns fixed or not determined. A systematic error, reported
    beside the standard error (``se_bem``) and added to it in quadrature (``se_total``)."""
    out = np.full(len(sf.x), np.nan)
    cols = np.flatnonzero(np.isfinite(sf.se))
    if cols.size:
        J = model.jacobian(sf.x)[:, cols]
        out[cols] = np.abs(np.linalg.lstsq(J, model.bem_rows(), rcond=None)[0])
    return out


#: the instrument's unknowns that enter a fit only where they lower its BIC at the scene fitted without them
OPTIONAL_INSTRUMENT = ("crosstalk_",)

#: the instrument's unknowns added one group at a time at the stated scene (name prefixes)
INSTRUMENT_GROUPS = (("scale", ("log_scale",)), ("multiplexer_classes", ("mux_",)),
                     ("multiplexer_crosstalk", ("crosstalk_",)),
                     ("channel_gains", ("channel_gain_",)), ("common_mode_and_ground", ("common_mode_", "ground_")))


def bic(residual, n_parameters: int) -> float:
    """Schwarz's criterion of a least-squares fit whose noise level is estimated from it: ``N ln(SSE / N) + k ln N``.

    >>> round(bic(np.ones(100), 2) - bic(np.ones(100), 1), 3)          # a parameter that explains nothing costs ln N
    4.605
    """
    r = np.asarray(residual, float)
    return float(len(r) * np.log(max(float(r @ r), 1e-300) / len(r)) + n_parameters * np.log(len(r)))


def _instrument_models(fit: _Fit, s_ref, s_ball, theta0: dict, ball_setups) -> list[dict]:
    """The instrument's groups added one at a time at the stated scene, each scored as the fits are (with the
    fitted rows' :func:`bic`)."""
    names = [u.name for u in fit.unknowns]
    solved = {su: fit.problem.solve(theta0, su) for su in [None, *ball_setups]}
    out, free = [], set()
    for label, prefixes in INSTRUMENT_GROUPS:
        new = {n for n in names[fit.nG:] if n.startswith(prefixes)}
        if not new:
            continue
        free |= new
        m, sf = fit.once(s_ref, s_ball, fixed=[n for n in names if n not in free])
        inst = m.inst(sf.x)
        lr = _reading(*solved[None], inst, fit.data.cls, fit.data.channel)
        rel = np.exp(lr - np.log(fit.data.Z_ref)) - 1
        row = {"model": label, "adds": sorted(new), "n_parameters": len(free), "bic": bic(m.residual(sf.x), len(free)),
               "empty_heldout_rms_rel": _rms(rel[~fit.data.train]), "empty_train_rms_rel": _rms(rel[fit.data.train]),
               "setups_rms_rel": {}, "setups_amplitude_largest_quarter_other_rows": {}}
        for su in ball_setups:
            sig = np.exp(_reading(*solved[su], inst, fit.data.cls, fit.data.channel) - lr) - 1
            sc = _signal_scores(sig, fit.data.signals[su])
            row["setups_rms_rel"][su] = sc["rms_rel"]
            row["setups_amplitude_largest_quarter_other_rows"][su] = [sc["amplitude_largest_quarter"],
                                                                      sc["amplitude_other_rows"]]
        fit.report(f"  {label}: empty held out {row['empty_heldout_rms_rel']:.3f}, set-ups "
                   + ", ".join(f"{k} {v:.2f}" for k, v in row["setups_rms_rel"].items()))
        out.append(row)
    return out


def unplaced(se, unknowns) -> list[str]:
    """The unknowns whose data do not place them within their bounds: no finite standard error, or a 95 % interval
    (+-1.96 se) wider than the bounds' span.

    >>> us = [Unknown("a", 0.0, -1.0, 1.0, 0.1), Unknown("b", 0.0, -1.0, 1.0, 0.1), Unknown("c", 0.0, -1.0, 1.0, 0.1)]
    >>> unplaced(np.array([0.1, np.nan, 0.6]), us)
    ['b', 'c']
    """
    return [u.name for u, e in zip(unknowns, np.asarray(se, float))
            if not np.isfinite(e) or 2 * 1.96 * e > u.upper - u.lower]


def _with_optional(fit: _Fit, without: tuple, optional: list, fixed: list, max_iterations: int) -> tuple:
    """A fit (``without``: :meth:`_Fit.chord`'s result with the ``optional`` unknowns held at their start)
    continued from its scene with them free; the one of lower :func:`bic` (free unknowns counted, the plain
    residuals of each fit's vector) is returned, with what was compared. So an instrument's group that could
    stand in for a scene's error at the stated scene is weighed at the scene fitted without it."""
    if not optional:
        return without, {}
    n_free = len([n for n in fit.names if n not in set(fixed) | set(optional)])
    b0 = bic(without[0].posterior_rows(without[1].x), n_free)
    with_ = fit.chord(without[2], without[3], fixed=fixed, ref_block=without[0].ref_block,
                      max_iterations=max_iterations)
    b1 = bic(with_[0].posterior_rows(with_[1].x), n_free + len(optional))
    chosen = (*with_[:4], without[4] + with_[4], with_[5]) if b1 < b0 else without
    return chosen, {"unknowns": optional, "bic_without": b0, "bic_with": b1, "kept": bool(b1 < b0)}


def scene_fit_summary(m: dict) -> str:
    """One line per fit of the scene fit's headline numbers (for the study's printout).

    >>> scene_fit_summary({"error": "the scene fit stopped: x"})
    'scene fit: the scene fit stopped: x'
    """
    if "error" in m:
        return f"scene fit: {m['error']}"
    lines = []
    for name, f in m["fits"].items():
        sc = f["scores"]
        sets = ", ".join(f"{k} {v['rms_rel']:.2f}{'' if v['held_out'] else ' (fitted)'}"
                         for k, v in sc["setups"].items())
        lines.append(f"scene fit ({name}) on the reference and {m['fit_setup']}: empty tank held-out drives "
                     f"{sc['empty_heldout_rms_rel']:.3f}; ball signals {sets}")
    lines.append(f"scene fit: {m['solves']['count']} BEM solves, {m['wall_s']:.0f} s")
    return "\n".join(lines)


def _fit_markdown(name: str, f: dict, stated: dict) -> list[str]:
    sc = f["scores"]
    lines = [f"### Fit `{name}`", "", f"Empty tank on held-out drives: {sc['empty_heldout_rms_rel']:.3f} RMS "
             f"(training drives {sc['empty_train_rms_rel']:.3f}). Converged: {f['converged']}.", "",
             "| set-up | signal error RMS / signal RMS | without outlying reference rows | floor | measured / model "
             "| on the model's largest quarter / the other rows |", "|---|---|---|---|---|---|"]
    for k, v in sc["setups"].items():
        lines.append(f"| {k}{'' if v['held_out'] else ' (fitted)'} | {v['rms_rel']:.3f} | "
                     f"{v['rms_rel_without_outlying_rows']:.3f} | {v['floor_rel']:.3f} | "
                     f"{v['measured_over_model_amplitude']:.2f} | {v['amplitude_largest_quarter']:.2f} / "
                     f"{v['amplitude_other_rows']:.2f} |")
    if sc["outlying_reference_rows"]:
        lines += ["", "Reference rows that every set-up's signal contradicts alike (the reference's value is off): "
                  + "; ".join(f"drive {r['drive']} measure {r['measure']}" for r in sc["outlying_reference_rows"])]
    lines += ["", "| unknown | stated | tolerance (prior) | fitted | standard error | the BEM's error | unit |",
              "|---|---|---|---|---|---|---|"]
    for k, v in f["fitted"].items():
        if k.startswith("channel_gain_"):
            continue
        se = "not determined" if v["se"] is None else f"{v['se']:.3g}"
        bem = f"{v['se_bem']:.3g}" if "se_bem" in v else ""
        st = f"{stated[k]:.4g}" if k in stated else ""
        tol = (f"{v['prior_sd']:.3g}" + (" (sets it)" if v["set_by_prior"] else "")) if "prior_sd" in v else ""
        lines.append(f"| {k} | {st} | {tol} | {v['value']:.4g} | {se} | {bem} | {v['unit']} |")
    u = f.get("unplaced") or {}
    placed = ("none" if not u else f"{', '.join(u['unplaced'])}: " + ("held at their stated values" if u["held"] else
              "left free") + f" (BIC held {u['bic_held']:.1f}, free {u['bic_free']:.1f})")
    return lines + ["", "Not placed by the data within their bounds (a first fit left them without a standard error "
                    "or with a 95 % interval wider than the bounds; the fit repeated with them held at their stated "
                    "values, the lower BIC kept): " + placed + ".",
                    "Not separable (directions of the unknowns the data do not determine): "
                    + ("; ".join(str(d["unknowns"]) for d in f["not_separable"]) or "none") + ".",
                    "Correlated above 0.95: " + ("; ".join(str(c["unknowns"]) for c in f["correlated"]) or "none")
                    + ".", "At a bound (its own or the surrogate's trust region): " + (", ".join(f["at_bound"]) or "none")
                    + ".", ""]


def scene_fit_markdown(m: dict) -> str:
    """The report's section on the scene fit: each fit's unknowns with standard errors, its scores, and what each
    change explains.

    >>> scene_fit_markdown({"error": "no ring"}).splitlines()[2]
    'Not computed: no ring'
    """
    lines = ["## The scene's unknowns fitted across set-ups", ""]
    if "error" in m:
        return "\n".join(lines + [f"Not computed: {m['error']}", ""])
    lines += [f"Fitted on the reference's training drives and `{m['fit_setup']}`; scored on the held-out drives and "
              f"the other set-ups, each solved on the BEM at the fitted scene. Noise model: {m['noise']['model']}. "
              f"{m['solves']['count']} BEM solves, {m['wall_s']:.0f} s.", ""]
    for name, f in m["fits"].items():
        lines += _fit_markdown(name, f, m["stated"])
    for name, o in m.get("optional_instrument", {}).items():
        if o:
            lines += [f"Fit `{name}`: the multiplexer classes' crosstalk ({', '.join(o['unknowns'])}) "
                      + ("entered" if o["kept"] else "left out") + f": BIC {o['bic_without']:.1f} without it, "
                      f"{o['bic_with']:.1f} with it, at the scene fitted without it.", ""]
    setups = list(next(iter(m["fits"].values()))["scores"]["setups"])
    lines += ["What each change explains (the instrument's groups added one at a time at the stated scene, then "
              "each fit):", "", "| model | parameters | empty tank held out | " + " | ".join(setups) + " |",
              "|---|---|---|" + "---|" * len(setups)]
    for r in m["what_each_explains"]:
        lines.append(f"| {r['model']} | {r['n_parameters']} | {r['empty_heldout_rms_rel']:.3f} | "
                     + " | ".join(f"{r['setups_rms_rel'][k]:.3f}" for k in setups) + " |")
    return "\n".join(lines + [""])
