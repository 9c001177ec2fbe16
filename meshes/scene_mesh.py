"""Meshing a whole scene, and refusing scenes a solver cannot use.

:func:`check_scene` looks at the true geometry: the sensor is a capsule (a
cylinder with hemispherical ends: the segment between the hemispheres'
centres, thickened by the radius) at its pose, the objects are exact
spheres, yawed boxes and vertical cylinders. It refuses, naming the parts,

* a sensor or object not wholly in the water (crossing or touching a wall,
  the floor or the free surface),
* two parts that intersect or touch (sensor/object, object/object).

:func:`mesh_scene` checks the scene, then meshes the sensor in the SENSOR
frame (the BEM reuses it for every pose), the tank graded towards the sensor
and the objects, in the tank frame. ``SceneMesh.combined()`` is everything
in the tank frame, one region per part.

Example
-------
>>> from electrosense.meshes import Pose, Scene, Sphere, Tank, preset
>>> from electrosense.meshes.scene_mesh import check_scene
>>> scene = Scene(preset("angels-2"), Pose(0.0, 0.0, 0.0, 0.0), Tank((1.0, 1.0, 1.0)),
...               (Sphere(centre_m=(0.05, 0.0, 0.0), radius_m=0.02),))
>>> try:
...     check_scene(scene)
... except ValueError as err:
...     print(err)
scene refused: object_1 (sphere) intersects the sensor
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from electrosense.meshes.cylinder_tank import CylinderTank
from electrosense.meshes.labelled_mesh import LabelledMesh, concatenate
from electrosense.meshes.object_mesh import mesh_object
from electrosense.meshes.objects import Box, Cylinder, Sphere
from electrosense.meshes.pose import Pose
from electrosense.meshes.scene import Scene
from electrosense.meshes.surface_electrodes import BodyElectrode
from electrosense.meshes.tank import TANK_REGIONS

__all__ = ["SceneError", "SceneMesh", "check_scene", "scene_problems", "mesh_scene", "sensor_axis_points_m",
           "trajectory_focus_m", "default_tank_edge_length_m", "mesh_tank_around", "DEFAULT_TANK_GRADING", "DEFAULT_TANK_NEAR_RATIO",
           "distance_to_object_m", "object_problems"]

#: growth of the tank's edge length per metre from the sensor. With the edge
#: length a twentieth of the sensor length at the sensor, angels-2 with its tip
#: 1 cm from a wall is within 0.1 % of the tank-converged K (0.36 % at 0.5 and
#: a tenth; validation/studies/bem_paper.py --convergence). Mid-tank in a box the
#: graded panels leave more: 0.034 % in a 0.77 x 0.52 m box, 0.013 % at 0.15 (a
#: tank map's reference, ``validation.simulation.tank_map.REFERENCE_TANK_GRADING``).
DEFAULT_TANK_GRADING = 0.25

#: the tank's edge at most this times its distance from the sensor's surface
#: (:func:`electrosense.meshes.tank_mesh.graded_size_function`). The grading
#: above grows from the sensor's axis, so a wall 5 mm from a tip kept panels
#: near the sensor's edge length. angels-4 heading at the end wall of the 1 m
#: tank, against a mesh with panels at most 0.125x that distance everywhere:
#: without this bound 0.23 % off (5 mm gap, 1 180 triangles), 0.086 % (2 cm);
#: with it 0.040 % (2 120 triangles, the same CPU time), 0.042 %; 0.25 gives
#: 0.025 % and 0.032 % for 1.7x the triangles. 10 cm from the wall both are
#: 0.03 % off, the far walls' share (a grading of 0.15 instead of 0.25 halves
#: that for 3x the triangles).
DEFAULT_TANK_NEAR_RATIO = 0.35


def default_tank_edge_length_m(sensor) -> float:
    """Default tank edge length nearest the sensor (m): a twentieth of the sensor's length."""
    return float(sensor.length_m) / 20.0


def mesh_tank_around(sensor, tank, focus_m, edge_length_m: float | None = None,
                     grading: float = DEFAULT_TANK_GRADING, near_ratio: float | None = DEFAULT_TANK_NEAR_RATIO
                     ) -> LabelledMesh:
    """A box or cylindrical tank's mesh graded towards a sensor at ``focus_m`` (its axis points, (P, 3) m).

    The edge is ``edge_length_m`` (default :func:`default_tank_edge_length_m`) at the focus, at most
    ``near_ratio`` times the distance from the sensor's surface, and grows by ``grading`` per metre away from
    it, to a quarter of a box's smaller side, or, in a cylinder, to at least 3 times the focus edge and the
    wall's own default (:func:`~electrosense.meshes.cylinder_tank_mesh.default_far_edge_length_m`): a 0.25 m
    radius tank at 3 h = 24 mm had 10 000 triangles (30 s a BEM pose), at its default 42 mm 2 300-3 500 (2-4 s),
    K within 0.002-0.023 % of the finer one (0.023 % at a 5 mm gap, a box's tank-mesh error); a big cylinder
    meshed at the focus edge everywhere had 34 000 triangles and 8.5 GB for its block alone.

    >>> from electrosense.meshes import Tank, preset
    >>> s = preset("angels-2")
    >>> axis = sensor_axis_points_m(Scene(s, Pose(0.0, 0.0, 0.0, 0.0), Tank((0.4, 0.3, 0.3))), 9)
    >>> mesh_tank_around(s, Tank((0.4, 0.3, 0.3)), axis).n_triangles > 0
    True
    """
    from electrosense.meshes.tank_mesh import mesh_tank

    h = default_tank_edge_length_m(sensor) if edge_length_m is None else float(edge_length_m)
    if isinstance(tank, CylinderTank):
        from electrosense.meshes.cylinder_tank_mesh import default_far_edge_length_m, mesh_cylinder_tank

        return mesh_cylinder_tank(tank, (), max(3 * h, default_far_edge_length_m(tank)), focus_m, grading=grading,
                                  near_ratio=near_ratio, focus_radius_m=sensor.radius_m, focus_edge_length_m=h)
    return mesh_tank(tank, h, focus_m, grading=grading, near_ratio=near_ratio, focus_radius_m=sensor.radius_m)


class SceneError(ValueError):
    """A scene that cannot be simulated; ``problems`` lists every reason."""

    def __init__(self, problems: list[str]):
        self.problems = list(problems)
        super().__init__("scene refused: " + "; ".join(self.problems))

    def __reduce__(self):   # rebuilt from its problems in another process (a map's workers), not from its message
        return type(self), (self.problems,)


# ------------------------------------------------------------------ the geometry
def sensor_axis_points_m(scene: Scene, n: int = 2) -> np.ndarray:
    """(n, 3) tank-frame points on the sensor's capsule core, from the tail sphere centre to the head's.

    The sensor is the set of points within ``radius_m`` of this segment.
    """
    s = scene.sensor
    half_core = 0.5 * s.length_m - s.radius_m
    x = np.linspace(-half_core, half_core, n)
    return scene.pose.to_tank(np.c_[x, np.zeros(n), np.zeros(n)])


def trajectory_focus_m(sensor, poses, n_per_pose: int = 5) -> np.ndarray:
    """(P * n, 3) points along the sensor's axis at every pose: a ``focus_m`` for one tank mesh per trajectory.

    Example
    -------
    >>> from electrosense.meshes import preset
    >>> trajectory_focus_m(preset("angels-2"), [[0.0, 0.0, 0.0, 0.0], [0.1, 0.0, 0.0, 0.0]], 2).round(2).tolist()
    [[-0.09, 0.0, 0.0], [0.09, 0.0, 0.0], [0.01, 0.0, 0.0], [0.19, 0.0, 0.0]]
    """
    from electrosense.meshes.pose import poses_array, sensor_to_tank

    half_core = 0.5 * sensor.length_m - sensor.radius_m
    x = np.linspace(-half_core, half_core, n_per_pose)
    axis = np.c_[x, np.zeros(n_per_pose), np.zeros(n_per_pose)]
    return sensor_to_tank(axis, poses_array(poses)).reshape(-1, 3)


def distance_to_object_m(obj, points_m: np.ndarray) -> np.ndarray:
    """Distance (...,) from points (..., 3) to the solid object (0 inside), tank frame (m)."""
    p = np.asarray(points_m, dtype=float) - np.asarray(obj.centre_m)
    if isinstance(obj, Sphere):
        return np.maximum(np.linalg.norm(p, axis=-1) - obj.radius_m, 0.0)
    if isinstance(obj, Box):
        c, s = np.cos(obj.yaw_rad), np.sin(obj.yaw_rad)
        q = np.stack([c * p[..., 0] + s * p[..., 1], -s * p[..., 0] + c * p[..., 1], p[..., 2]], axis=-1)
        return np.linalg.norm(np.maximum(np.abs(q) - 0.5 * np.asarray(obj.size_m), 0.0), axis=-1)
    if isinstance(obj, Cylinder):
        radial = np.maximum(np.hypot(p[..., 0], p[..., 1]) - obj.radius_m, 0.0)
        axial = np.maximum(np.abs(p[..., 2]) - 0.5 * obj.height_m, 0.0)
        return np.hypot(radial, axial)
    raise TypeError(f"unknown object type {type(obj).__name__}")


def _segment_distance_to_object_m(a: np.ndarray, b: np.ndarray, obj) -> float:
    """Distance from the segment a-b to a convex object (convex in the segment parameter)."""
    t = np.linspace(0.0, 1.0, 65)
    d = distance_to_object_m(obj, a + t[:, None] * (b - a))
    i = int(np.argmin(d))
    lo, hi = t[max(i - 1, 0)], t[min(i + 1, len(t) - 1)]
    res = minimize_scalar(lambda s: float(distance_to_object_m(obj, a + s * (b - a))), bounds=(lo, hi),
                          method="bounded", options={"xatol": 1e-10})
    return float(min(d[i], res.fun))


def objects_focus_m(objects) -> np.ndarray | None:
    """The points a tank mesh is graded towards for ``objects`` (their surfaces' furthest reach along +-x, +-y,
    +-z), (6 per object, 3); None for none. Given as ``tank_focus_m`` to every scene of a series (an empty tank and
    the same tank with objects), it meshes the tank alike in all: an object's difference signal is then not the
    difference of two tank meshes.

    >>> from electrosense.meshes.objects import Sphere
    >>> objects_focus_m([Sphere((0.0, 0.0, 0.0), radius_m=0.02)]).shape
    (6, 3)
    """
    return np.concatenate([_object_extreme_points_m(o) for o in objects]) if len(objects) else None


def _object_extreme_points_m(obj) -> np.ndarray:
    """Points of the object's surface that reach furthest along +-x, +-y, +-z (tank frame)."""
    c = np.asarray(obj.centre_m)
    if isinstance(obj, Sphere):
        return c + obj.radius_m * np.vstack([np.eye(3), -np.eye(3)])
    if isinstance(obj, Box):
        corners = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)]) * 0.5 * np.asarray(obj.size_m)
        cy, sy = np.cos(obj.yaw_rad), np.sin(obj.yaw_rad)
        R = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
        return c + corners @ R.T
    if isinstance(obj, Cylinder):
        r, h = obj.radius_m, 0.5 * obj.height_m
        rim = np.array([[r, 0], [-r, 0], [0, r], [0, -r]])
        return c + np.vstack([np.c_[rim, np.full(4, z)] for z in (-h, h)])
    raise TypeError(f"unknown object type {type(obj).__name__}")


def _surface_samples_m(obj, n: int = 24) -> np.ndarray:
    """Points on an object's surface, about n across, for object/object contact tests."""
    h = 2 * obj.bounding_radius_m / n
    return mesh_object(obj, edge_length_m=h).vertices_m


def _object_name(i: int, obj) -> str:
    kind = type(obj).__name__.lower()
    return f"object_{i} ({kind}{' ' + repr(obj.name) if obj.name else ''})"


def scene_problems(scene: Scene) -> list[str]:
    """Every reason why the scene cannot be simulated (empty list: the scene is fine)."""
    problems = []
    s = scene.sensor
    tank = scene.tank
    if s is None:
        return _sensorless_problems(scene)
    core = sensor_axis_points_m(scene)
    if tank is not None:
        # the capsule is inside the (convex) water box iff both core ends are >= radius from every plane
        gap = tank.distance_to_boundary_m(core).min(axis=0) - s.radius_m
        crossings = _boundary_crossings(gap)
        if crossings:
            problems.append(f"the sensor (pose {_pose_text(scene.pose)}) {crossings}")
    for i, obj in enumerate(scene.objects, start=1):
        name = _object_name(i, obj)
        if tank is not None:
            crossings = _boundary_crossings(tank.distance_to_boundary_m(_object_extreme_points_m(obj)).min(axis=0))
            if crossings:
                problems.append(f"{name} {crossings}")
        d = _segment_distance_to_object_m(core[0], core[1], obj) - s.radius_m
        if d <= _TOUCH_M:
            problems.append(f"{name} {'intersects' if d < -_TOUCH_M else 'touches'} the sensor")
    return problems + _touching_objects(scene.objects)


def _touching_objects(objects) -> list[str]:
    """Every pair of objects that intersect or touch."""
    return [f"{_object_name(i, a)} and {_object_name(j, b)} intersect or touch"
            for i, a in enumerate(objects, start=1) for j, b in enumerate(objects[i:], start=i + 1)
            if _body_gap_m(a, b) <= _TOUCH_M]


def _body_gap_m(body, other) -> float:
    """Smallest distance (m) between two bodies' surfaces (exact for a sphere, sampled otherwise); < 0: overlap.
    Bodies whose bounding spheres are apart are not sampled (their gap is then a lower bound, > 0)."""
    apart = float(np.linalg.norm(np.subtract(body.centre_m, other.centre_m)))
    if apart > body.bounding_radius_m + other.bounding_radius_m:
        return apart - body.bounding_radius_m - other.bounding_radius_m
    if isinstance(body, Sphere):
        return float(distance_to_object_m(other, np.asarray(body.centre_m))) - body.radius_m
    if isinstance(other, Sphere):
        return float(distance_to_object_m(body, np.asarray(other.centre_m))) - other.radius_m
    return float(min(distance_to_object_m(other, _surface_samples_m(body)).min(),
                     distance_to_object_m(body, _surface_samples_m(other)).min()))


def _body_electrode_problems(scene: Scene) -> list[str]:
    """Electrodes in the water out of it, touching a boundary, an object, the sensor or each other."""
    problems = []
    bodies = [(i, e) for i, e in enumerate(scene.electrodes, start=scene.n_sensor_electrodes + 1)
              if isinstance(e, BodyElectrode)]
    names = scene.tank.region_names if hasattr(scene.tank, "region_names") else TANK_REGIONS
    core = sensor_axis_points_m(scene) if scene.sensor is not None else None

    def named(i, e):
        return f"electrode {i} ({type(e.body).__name__.lower()}{' ' + repr(e.name) if e.name else ''})"

    for k, (i, e) in enumerate(bodies):
        crossings = _boundary_crossings(
            scene.tank.distance_to_boundary_m(_object_extreme_points_m(e.body)).min(axis=0), names)
        if crossings:
            problems.append(f"{named(i, e)} {crossings}")
        for j, obj in enumerate(scene.objects, start=1):
            if _body_gap_m(e.body, obj) <= _TOUCH_M:
                problems.append(f"{named(i, e)} and {_object_name(j, obj)} intersect or touch")
        if core is not None and (_segment_distance_to_object_m(core[0], core[1], e.body) - scene.sensor.radius_m
                                 <= _TOUCH_M):
            problems.append(f"{named(i, e)} intersects or touches the sensor")
        for i2, e2 in bodies[k + 1:]:
            if _body_gap_m(e.body, e2.body) <= _TOUCH_M:
                problems.append(f"{named(i, e)} and {named(i2, e2)} intersect or touch")
    return problems


def _sensorless_problems(scene: Scene) -> list[str]:
    """Objects out of the water or touching each other (any shapes), in a scene without a sensor."""
    return object_problems(scene.tank, scene.objects)


def object_problems(tank, objects) -> list[str]:
    """Every reason why fixed ``objects`` cannot stand in ``tank`` (None: unbounded water), wherever a sensor goes.

    Example
    -------
    >>> from electrosense.meshes import Sphere, Tank
    >>> object_problems(Tank((0.6, 0.4, 0.3)), (Sphere(centre_m=(0.29, 0.0, 0.0), radius_m=0.02),))
    ['object_1 (sphere) is out of the water across the wall_x+ (by 0.01 m)']
    """
    problems = []
    names = tank.region_names if hasattr(tank, "region_names") else TANK_REGIONS
    for i, obj in enumerate(objects, start=1):
        if tank is None:
            continue
        gap = tank.distance_to_boundary_m(_object_extreme_points_m(obj)).min(axis=0)
        crossings = _boundary_crossings(gap, names)
        if crossings:
            problems.append(f"{_object_name(i, obj)} {crossings}")
    return problems + _touching_objects(tuple(objects))


#: gaps (m) below this count as contact: a solver cannot separate touching surfaces
_TOUCH_M = 1e-9


def _boundary_crossings(gap_m: np.ndarray, names=TANK_REGIONS) -> str:
    """'is out of the water across the wall_x+ (by 0.01 m) and touches the floor', or ''."""
    out = [f"the {name} (by {-g:.3g} m)" for name, g in zip(names, gap_m) if g < -_TOUCH_M]
    touch = [f"the {name}" for name, g in zip(names, gap_m) if abs(g) <= _TOUCH_M]
    text = []
    if out:
        text.append("is out of the water across " + ", ".join(out))
    if touch:
        text.append("touches " + ", ".join(touch))
    return " and ".join(text)


def _pose_text(pose: Pose) -> str:
    return f"x={pose.x_m:g} m, y={pose.y_m:g} m, z={pose.z_m:g} m, yaw={pose.yaw_rad:g} rad"


def check_scene(scene: Scene) -> Scene:
    """Return the scene unchanged, or raise :class:`SceneError` (a ``ValueError``) naming every problem."""
    problems = scene_problems(scene) + _body_electrode_problems(scene)
    if problems:
        raise SceneError(problems)
    return scene


# ---------------------------------------------------------------------- meshing
@dataclass
class SceneMesh:
    """The meshes of a scene's parts.

    Attributes
    ----------
    sensor : LabelledMesh
        The sensor in the SENSOR frame (region ``"sensor"``).
    pose : Pose
        Where the sensor is in the tank frame.
    tank : LabelledMesh or None
        The water box in the tank frame (regions ``TANK_REGIONS``), or
        ``None`` for unbounded water.
    objects : tuple of LabelledMesh
        One mesh per object, tank frame, regions ``"object_1"``, ...
    electrode_bodies : tuple of LabelledMesh
        One mesh per electrode that is a body in the water (a
        :class:`~electrosense.meshes.surface_electrodes.BodyElectrode`), all
        its faces labelled with its electrode number; tank frame.
    """

    sensor: LabelledMesh | None
    pose: Pose
    tank: LabelledMesh | None = None
    objects: tuple[LabelledMesh, ...] = ()
    electrode_bodies: tuple[LabelledMesh, ...] = ()

    @property
    def sensor_in_tank(self) -> LabelledMesh | None:
        """The sensor mesh moved to its pose (tank frame); ``None`` without a sensor."""
        return None if self.sensor is None else self.sensor.transformed(self.pose)

    @property
    def n_triangles(self) -> int:
        return ((self.sensor.n_triangles if self.sensor is not None else 0) + (self.tank.n_triangles if self.tank else 0)
                + sum(o.n_triangles for o in self.objects + self.electrode_bodies))

    def combined(self) -> LabelledMesh:
        """All parts in the tank frame: the sensor, the tank, the objects, then the electrodes in the water."""
        parts = (([] if self.sensor is None else [self.sensor_in_tank]) + ([self.tank] if self.tank is not None else [])
                 + list(self.objects) + list(self.electrode_bodies))
        return concatenate(parts)


def mesh_scene(scene: Scene, edge_length_m: float | None = None, *, tank_edge_length_m: float | None = None,
               tank_grading: float = DEFAULT_TANK_GRADING, tank_focus_m=None, object_edge_length_m: float | None = None,
               tank_near_ratio: float | None = DEFAULT_TANK_NEAR_RATIO, check: bool = True,
               **sensor_options) -> SceneMesh:
    """Check and mesh a scene.

    Parameters
    ----------
    scene : Scene
    edge_length_m : float, optional
        Sensor edge length, passed to :func:`electrosense.meshes.sensor_mesh.mesh_sensor`.
    tank_edge_length_m : float, optional
        Tank edge length nearest the sensor (default
        :func:`default_tank_edge_length_m`); it grows by ``tank_grading`` per
        metre away from it.
    tank_focus_m : (P, 3) array, optional
        Tank-frame points to grade the tank towards (default: the sensor's
        axis at its pose; give a whole trajectory to reuse one tank mesh).
    tank_near_ratio : float or None
        The tank's edge at most this times its distance from the sensor's
        surface around the focus (:data:`DEFAULT_TANK_NEAR_RATIO`); None: no
        such bound. Box tanks with a sensor.
    object_edge_length_m : float, optional
        Edge length of the objects (default: from each object's size).
    check : bool
        Refuse bad scenes first (:func:`check_scene`); default True.
    **sensor_options
        Further options of ``mesh_sensor`` (grading...).

    Example
    -------
    >>> from electrosense.meshes import Pose, Scene, Tank, preset
    >>> sm = mesh_scene(Scene(preset("angels-2"), Pose(0.1, 0.0, 0.0, 0.0), Tank((0.6, 0.4, 0.3))))
    >>> sm.combined().region_names[:2]
    ('sensor', 'wall_x-')
    """
    from electrosense.meshes.sensor_mesh import mesh_sensor
    from electrosense.meshes.tank_mesh import mesh_tank

    if check:
        check_scene(scene)
    if scene.sensor is None or isinstance(scene.tank, CylinderTank) or scene.electrodes:
        return _mesh_electrode_scene(scene, edge_length_m, tank_edge_length_m, tank_grading, tank_focus_m,
                                     object_edge_length_m, **sensor_options)
    sensor = mesh_sensor(scene.sensor, edge_length_m=edge_length_m, **sensor_options)
    if sensor.region_names != ("sensor",) and len(sensor.region_names) == 1:
        sensor = sensor.with_region_names(("sensor",))
    tank = None
    if scene.tank is not None:
        focus = sensor_axis_points_m(scene, 9) if tank_focus_m is None else tank_focus_m
        h_tank = default_tank_edge_length_m(scene.sensor) if tank_edge_length_m is None else tank_edge_length_m
        tank = mesh_tank(scene.tank, h_tank, focus, grading=tank_grading, near_ratio=tank_near_ratio,
                         focus_radius_m=scene.sensor.radius_m)
    objects = tuple(
        mesh_object(obj, object_edge_length_m, region_name=f"object_{i}") for i, obj in enumerate(scene.objects, start=1)
    )
    return SceneMesh(sensor=sensor, pose=scene.pose, tank=tank, objects=objects)


def _mesh_electrode_scene(scene: Scene, edge_length_m, tank_edge_length_m, tank_grading, tank_focus_m,
                          object_edge_length_m, edge_fraction=None, electrode_grading=None,
                          **sensor_options) -> SceneMesh:
    """A scene with electrodes on its tank, or a cylindrical tank, or no sensor."""
    from electrosense.meshes.cylinder_tank_mesh import mesh_cylinder_tank
    from electrosense.meshes.sensor_mesh import mesh_sensor
    from electrosense.meshes.surface_electrodes import DEFAULT_EDGE_FRACTION, DEFAULT_ELECTRODE_GRADING

    sensor = None
    focus = [] if tank_focus_m is None else [np.asarray(tank_focus_m, float).reshape(-1, 3)]
    if scene.sensor is not None:
        sensor = mesh_sensor(scene.sensor, edge_length_m=edge_length_m, **sensor_options)
        if sensor.region_names != ("sensor",) and len(sensor.region_names) == 1:
            sensor = sensor.with_region_names(("sensor",))
        if tank_focus_m is None:
            focus.append(sensor_axis_points_m(scene, 9))
    if tank_focus_m is None:
        focus += [_object_extreme_points_m(o) for o in scene.objects]
    first = scene.n_sensor_electrodes + 1
    on_tank = [i for i, e in enumerate(scene.electrodes) if not isinstance(e, BodyElectrode)]
    bodies = [i for i, e in enumerate(scene.electrodes) if isinstance(e, BodyElectrode)]
    focus += [np.asarray(scene.electrodes[i].centre_m, float)[None, :] for i in bodies]
    if isinstance(scene.tank, CylinderTank):
        tank = mesh_cylinder_tank(
            scene.tank, [scene.electrodes[i] for i in on_tank], tank_edge_length_m,
            np.concatenate(focus) if focus else None,
            grading=tank_grading if tank_grading != DEFAULT_TANK_GRADING else 0.5,
            edge_fraction=DEFAULT_EDGE_FRACTION if edge_fraction is None else edge_fraction,
            electrode_grading=DEFAULT_ELECTRODE_GRADING if electrode_grading is None else electrode_grading,
            first_label=1)
    elif not on_tank:       # a box tank with electrodes in the water only: its walls carry none
        from electrosense.meshes.tank_mesh import mesh_tank

        tank = mesh_tank(scene.tank, tank_edge_length_m, np.concatenate(focus) if focus else None, grading=tank_grading)
    else:
        raise SceneError([f"electrodes on a {type(scene.tank).__name__}'s walls are not meshed yet: use a "
                          "cylindrical tank (electrodes in the water are meshed in either)"])
    # the tank's labels 1..k to scene numbers (electrodes in the water may come between)
    tank.electrode = np.r_[0, first + np.asarray(on_tank, np.int64)][tank.electrode]
    electrode_bodies = tuple(_body_electrode_mesh(scene.electrodes[i], first + i, object_edge_length_m)
                             for i in bodies)
    objects = tuple(
        mesh_object(obj, object_edge_length_m, region_name=f"object_{i}") for i, obj in enumerate(scene.objects, start=1)
    )
    return SceneMesh(sensor=sensor, pose=scene.pose, tank=tank, objects=objects, electrode_bodies=electrode_bodies)


#: edge length of a sphere electrode's mesh, as a fraction of its radius (no edge to grade towards): two spheres
#: 20 radii apart in a large tank are within 0.5 % of the closed form at this size, 0.2 % at 0.25
#: (tests/test_real_tank.py)
SPHERE_ELECTRODE_EDGE_FRACTION = 0.4


def _body_electrode_mesh(e, label: int, edge_length_m=None) -> LabelledMesh:
    """The mesh of an electrode in the water, every face labelled ``label``, region ``electrode_<label>``.

    A sphere is meshed at :data:`SPHERE_ELECTRODE_EDGE_FRACTION` of its radius
    (or ``edge_length_m``) and its inscribed polyhedron scaled about the
    centre to the sphere's area (the electrode's area exact); a rod or a
    block as an object of its size.
    """
    body = e.body
    if not isinstance(body, Sphere):
        m = mesh_object(body, edge_length_m, region_name=f"electrode_{label}")
        return LabelledMesh(m.vertices_m, m.faces, np.full(m.n_triangles, label, np.int64), m.region, m.region_names)
    h = SPHERE_ELECTRODE_EDGE_FRACTION * body.radius_m if edge_length_m is None else edge_length_m
    m = mesh_object(body, h, region_name=f"electrode_{label}")
    c = np.asarray(body.centre_m, float)
    scale = np.sqrt(4 * np.pi * body.radius_m ** 2 / m.to_trimesh().area)
    return LabelledMesh(c + scale * (m.vertices_m - c), m.faces, np.full(m.n_triangles, label, np.int64), m.region,
                        m.region_names)
