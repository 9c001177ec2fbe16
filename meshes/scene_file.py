"""Scene files: a user's bench set-up in a small TOML file.

::

    # my_bench.toml -- lengths in metres, angles in radians, tank frame
    [tank]                      # leave the table out for unbounded water
    size_m = [1.0, 0.6, 0.5]    # inner Lx, Ly, Lz
    water_depth_m = 0.4         # default: Lz

    [sensor]
    preset = "angels-4"         # or: file = "my_sensor.json" (relative to this file)
    pose = [0.0, 0.0, 0.0, 0.0] # x_m, y_m, z_m, yaw_rad of the sensor centre
    emitter = 4                 # optional, default: the last electrode

    [[objects]]
    shape = "sphere"            # sphere | box | cylinder
    centre_m = [0.15, 0.08, 0.0]
    radius_m = 0.02
    material = "conducting"     # insulating | conducting | conductivity in S/m
    name = "steel ball"         # optional

    [[objects]]
    shape = "box"
    centre_m = [-0.2, 0.1, -0.05]
    size_m = [0.05, 0.05, 0.1]
    yaw_rad = 0.3               # optional
    material = "insulating"

    [[objects]]
    shape = "cylinder"          # vertical pole
    centre_m = [0.25, -0.15, 0.0]
    radius_m = 0.01
    height_m = 0.2
    material = 0.5

    [water]                     # optional physics, read by the simulating commands
    sigma_S_per_m = 0.05

A cylindrical tank with electrodes of its own (a tank without a sensor is
allowed when it has electrodes)::

    [tank]
    shape = "cylinder"
    radius_m = 0.15             # at the top of the tank
    floor_radius_m = 0.13       # optional: a tapered (frustum) wall
    height_m = 0.30
    water_depth_m = 0.28

    [[electrode_ring]]          # n discs evenly round the wall; one table per ring
    n = 16
    z_m = -0.05
    radius_m = 0.004
    first_angle_rad = 0.0

    [[electrodes]]              # more electrodes: disc (centre on a boundary), plate (a whole region)
    shape = "disc"              # or sphere / rod (a metal ball / vertical rod in the water: centre,
                                # radius, and the rod's length_m)
    centre_m = [0.0, 0.0, -0.15]
    radius_m = 0.005

    [tolerance]                 # optional: how well the description knows a length (one standard
    ring_radius_m = 0.008       # deviation; the real-tank scene fit's priors; inf: none)

Unknown tables or keys are refused (a misspelt key must not be silently
ignored). Tables other than ``tank``, ``sensor`` and ``objects`` that the
geometry does not use (``[water]``...) are returned by
:func:`load_scene_settings`.

Example
-------
>>> import tempfile, pathlib
>>> from electrosense.meshes.scene_file import load_scene
>>> path = pathlib.Path(tempfile.mkdtemp()) / "bench.toml"
>>> _ = path.write_text('[tank]\\nsize_m = [1, 1, 0.5]\\n[sensor]\\npreset = "angels-2"\\npose = [0.1, 0, 0, 0]\\n')
>>> scene = load_scene(path)
>>> scene.sensor.name, scene.pose.x_m, scene.tank.water_depth_m
('angels-2', 0.1, 0.5)
"""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import tomllib

from electrosense.meshes.cylinder_tank import CylinderTank
from electrosense.meshes.objects import Box, Cylinder, Sphere, parse_material
from electrosense.meshes.pose import Pose
from electrosense.meshes.scene import Scene
from electrosense.meshes.sensor import load_sensor
from electrosense.meshes.surface_electrodes import BodyElectrode, DiscElectrode, PlateElectrode
from electrosense.meshes.tank import Tank

__all__ = ["load_scene", "load_scene_settings", "scene_sensor_file", "save_scene", "scene_to_toml", "apply_overrides",
           "SceneFileError"]

#: tables that carry physics or run settings rather than geometry; passed through
SETTINGS_TABLES = ("water", "bem", "psm", "contact", "protocol", "tolerance")

_SHAPES = {
    "sphere": (Sphere, {"radius_m"}),
    "box": (Box, {"size_m", "yaw_rad"}),
    "cylinder": (Cylinder, {"radius_m", "height_m"}),
}


class SceneFileError(ValueError):
    """A scene file that cannot be read; the message names the file and the entry."""


def _read_toml(path: Path) -> dict:
    if not path.exists():
        raise SceneFileError(f"{path}: no such scene file")
    try:
        return tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise SceneFileError(f"{path}: not valid TOML: {exc}") from None


def _unknown(path, where: str, table: dict, allowed: set[str]):
    extra = sorted(set(table) - allowed)
    if extra:
        raise SceneFileError(f"{path}: {where} has unknown key(s) {', '.join(extra)}; allowed: {', '.join(sorted(allowed))}")


def _floats(path, where: str, value, n: int) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in (value if isinstance(value, (list, tuple)) else [value]))
    except (TypeError, ValueError):
        raise SceneFileError(f"{path}: {where} must be {n} number(s), got {value!r}") from None
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise SceneFileError(f"{path}: {where} must be {n} finite number(s), got {value!r}")
    return values


def load_scene(path: str | Path) -> Scene:
    """Read a scene file (see the module docstring for the format).

    Raises :class:`SceneFileError` naming the file and the faulty entry.
    The scene is not checked for collisions here; see
    :func:`electrosense.meshes.scene_mesh.check_scene`.
    """
    path = Path(path)
    data = _read_toml(path)
    _unknown(path, "the file", data, {"tank", "sensor", "objects", "electrodes", "electrode_ring", *SETTINGS_TABLES})
    try:
        tank = None
        if "tank" in data and str(data["tank"].get("shape", "box")) == "cylinder":
            t = data["tank"]
            _unknown(path, "[tank]", t, {"shape", "radius_m", "height_m", "water_depth_m", "floor_radius_m"})
            for key in ("radius_m", "height_m"):
                if key not in t:
                    raise SceneFileError(f"{path}: a cylindrical [tank] needs {key}")
            depth = t.get("water_depth_m")
            tank = CylinderTank(_floats(path, "[tank] radius_m", t["radius_m"], 1)[0],
                                _floats(path, "[tank] height_m", t["height_m"], 1)[0],
                                None if depth is None else _floats(path, "[tank] water_depth_m", depth, 1)[0],
                                None if "floor_radius_m" not in t else
                                _floats(path, "[tank] floor_radius_m", t["floor_radius_m"], 1)[0])
        elif "tank" in data:
            t = data["tank"]
            _unknown(path, "[tank]", t, {"shape", "size_m", "water_depth_m"})
            if str(t.get("shape", "box")) != "box":
                raise SceneFileError(f"{path}: [tank] shape {t.get('shape')!r}: expected box or cylinder")
            if "size_m" not in t:
                raise SceneFileError(f"{path}: [tank] needs size_m = [Lx, Ly, Lz] (inner size, m)")
            depth = t.get("water_depth_m")
            tank = Tank(_floats(path, "[tank] size_m", t["size_m"], 3),
                        None if depth is None else _floats(path, "[tank] water_depth_m", depth, 1)[0])

        electrodes = _scene_electrodes(path, data, tank)
        if "sensor" not in data:
            if not electrodes:
                raise SceneFileError(f"{path}: a [sensor] table is needed (preset = \"angels-4\" or file = \"...\"), "
                                     "or electrodes of the scene ([[electrodes]], [electrode_ring])")
            sensor, pose = None, Pose()
        else:
            sensor, pose = _sensor(path, data["sensor"])
        objects = _objects(path, data)
        return Scene(sensor=sensor, pose=pose, tank=tank, objects=tuple(objects), electrodes=tuple(electrodes))
    except SceneFileError:
        raise
    except ValueError as exc:  # from the geometry types: prefix the file
        raise SceneFileError(f"{path}: {exc}") from None


def _scene_electrodes(path, data, tank) -> list:
    """``[electrode_ring]`` (n discs evenly round a cylindrical tank's wall; ``[[electrode_ring]]`` for several
    rings, numbered in file order) then ``[[electrodes]]``, in order."""
    out = []
    rings = data.get("electrode_ring", [])
    rings = [rings] if isinstance(rings, dict) else rings
    for j, r in enumerate(rings, start=1):
        where = "[electrode_ring]" if isinstance(data["electrode_ring"], dict) else f"[[electrode_ring]] number {j}"
        if not isinstance(r, dict):
            raise SceneFileError(f"{path}: {where} must be a table")
        _unknown(path, where, r, {"n", "z_m", "radius_m", "first_angle_rad", "clockwise", "name"})
        if not isinstance(tank, CylinderTank):
            raise SceneFileError(f"{path}: {where} needs a cylindrical [tank] (shape = \"cylinder\")")
        for key in ("n", "z_m", "radius_m"):
            if key not in r:
                raise SceneFileError(f"{path}: {where} needs {key}")
        n = int(r["n"])
        if n < 1:
            raise SceneFileError(f"{path}: {where} n must be >= 1, got {n}")
        sign = -1.0 if r.get("clockwise", False) else 1.0
        phi = float(r.get("first_angle_rad", 0.0)) + sign * 2 * math.pi * np.arange(n) / n
        z = _floats(path, f"{where} z_m", r["z_m"], 1)[0]
        a = _floats(path, f"{where} radius_m", r["radius_m"], 1)[0]
        name = str(r.get("name", "ring" if len(rings) == 1 else f"ring {j}"))
        R = float(tank.radius_at(z))
        out += [DiscElectrode((R * math.cos(p), R * math.sin(p), z), a, f"{name} {k}") for k, p in enumerate(phi, 1)]
    entries = data.get("electrodes", [])
    if not isinstance(entries, list):
        raise SceneFileError(f"{path}: electrodes must be an array of tables ([[electrodes]])")
    for i, e in enumerate(entries, start=1):
        where = f"[[electrodes]] number {i}"
        _unknown(path, where, e, {"shape", "centre_m", "radius_m", "length_m", "region", "name"})
        shape = str(e.get("shape", "disc"))
        if shape == "disc":
            if "centre_m" not in e or "radius_m" not in e:
                raise SceneFileError(f"{path}: {where} (disc) needs centre_m and radius_m")
            out.append(DiscElectrode(_floats(path, f"{where} centre_m", e["centre_m"], 3),
                                     _floats(path, f"{where} radius_m", e["radius_m"], 1)[0], str(e.get("name", ""))))
        elif shape in ("sphere", "rod"):
            need = ("centre_m", "radius_m") + (("length_m",) if shape == "rod" else ())
            if any(k not in e for k in need):
                raise SceneFileError(f"{path}: {where} ({shape}) needs {', '.join(need)}")
            c = _floats(path, f"{where} centre_m", e["centre_m"], 3)
            r = _floats(path, f"{where} radius_m", e["radius_m"], 1)[0]
            body = (Sphere(c, radius_m=r) if shape == "sphere"
                    else Cylinder(c, radius_m=r, height_m=_floats(path, f"{where} length_m", e["length_m"], 1)[0]))
            out.append(BodyElectrode(body, str(e.get("name", ""))))
        elif shape == "plate":
            if "region" not in e:
                raise SceneFileError(f"{path}: {where} (plate) needs region = \"floor\" (a tank region)")
            out.append(PlateElectrode(str(e["region"]), str(e.get("name", ""))))
        else:
            raise SceneFileError(f"{path}: {where} has shape {shape!r}; expected disc, plate, sphere or rod")
    return out


def _sensor(path, s):
    _unknown(path, "[sensor]", s, {"preset", "file", "pose", "emitter"})
    if ("preset" in s) == ("file" in s):
        raise SceneFileError(f"{path}: [sensor] needs exactly one of preset = \"...\" or file = \"...\"")
    sensor = load_sensor(s["preset"]) if "preset" in s else load_sensor(s["file"], relative_to=path.parent)
    if "emitter" in s:
        sensor = sensor.with_emitter(int(s["emitter"]))
    pose = Pose(*_floats(path, "[sensor] pose", s.get("pose", [0, 0, 0, 0]), 4))
    return sensor, pose


def _objects(path, data) -> list:
    objects = []
    entries = data.get("objects", [])
    if not isinstance(entries, list):
        raise SceneFileError(f"{path}: objects must be an array of tables ([[objects]])")
    for i, o in enumerate(entries, start=1):
        where = f"[[objects]] number {i}"
        shape = str(o.get("shape", "")).lower()
        if shape not in _SHAPES:
            raise SceneFileError(f"{path}: {where} has shape {o.get('shape')!r}; expected sphere, box or cylinder")
        cls, keys = _SHAPES[shape]
        _unknown(path, where, o, {"shape", "centre_m", "material", "name"} | keys)
        if "centre_m" not in o:
            raise SceneFileError(f"{path}: {where} needs centre_m = [x, y, z] (m, tank frame)")
        kwargs = {"centre_m": _floats(path, f"{where} centre_m", o["centre_m"], 3),
                  "conductivity_S_per_m": parse_material(o.get("material", "insulating")),
                  "name": str(o.get("name", ""))}
        for key in keys & set(o):
            n = 3 if key == "size_m" else 1
            value = _floats(path, f"{where} {key}", o[key], n)
            kwargs[key] = value if n == 3 else value[0]
        try:
            objects.append(cls(**kwargs))
        except ValueError as exc:   # a length that is not positive
            raise SceneFileError(f"{path}: {where}: {exc}") from None
    return objects


def scene_sensor_file(path: str | Path) -> Path | None:
    """The sensor file a scene file's ``[sensor]`` table names, resolved against the scene's folder (None where
    it names a preset or no sensor): what a bench log made from the scene can name (read the scene with
    :func:`load_scene`, which checks the entry, first).

    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> _ = (folder / "bench.toml").write_text('[sensor]\\nfile = "probe.json"\\n')
    >>> scene_sensor_file(folder / "bench.toml") == (folder / "probe.json").resolve()
    True
    """
    path = Path(path)
    entry = _read_toml(path).get("sensor", {})
    if not isinstance(entry, dict) or "file" not in entry:
        return None
    return (path.parent / str(entry["file"])).resolve()


def load_scene_settings(path: str | Path) -> dict:
    """The non-geometry tables of a scene file (``{"water": {"sigma_S_per_m": 0.05}}``...)."""
    path = Path(path)
    data = _read_toml(path)
    water = data.get("water", {})
    if not isinstance(water, dict):
        raise SceneFileError(f"{path}: [water] must be a table")
    if "sigma_S_per_m" in water:   # read by every simulating command: checked once, here
        sigma = water["sigma_S_per_m"]
        if isinstance(sigma, bool) or not isinstance(sigma, (int, float)) or not (math.isfinite(sigma) and sigma > 0):
            raise SceneFileError(f"{path}: [water] sigma_S_per_m must be a positive conductivity (S/m), got {sigma!r}")
    return {k: v for k, v in data.items() if k in SETTINGS_TABLES}


def _toml_value(v) -> str:
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    v = float(v)
    return "inf" if math.isinf(v) else repr(v)


def scene_to_toml(scene: Scene, sensor_file: str | None = None, settings: dict | None = None) -> str:
    """The scene as scene-file text (a preset sensor by name, else ``sensor_file``)."""
    from electrosense.meshes.sensor import PRESETS, preset

    lines = []
    if scene.tank is not None:
        lines += ["[tank]", f"size_m = {_toml_value(scene.tank.size_m)}",
                  f"water_depth_m = {_toml_value(scene.tank.water_depth_m)}", ""]
    lines.append("[sensor]")
    s = scene.sensor
    if sensor_file is not None:
        lines.append(f"file = {_toml_value(sensor_file)}")
    elif s.name in PRESETS and replace(preset(s.name), emitter=s.emitter) == s:
        lines.append(f"preset = {_toml_value(s.name)}")
    else:
        raise ValueError(f"sensor {s.name!r} is not a preset: give sensor_file (and save it with save_sensor)")
    lines += [f"pose = {_toml_value(scene.pose.as_array())}", f"emitter = {s.emitter}", ""]
    for obj in scene.objects:
        shape = type(obj).__name__.lower()
        lines += ["[[objects]]", f"shape = {_toml_value(shape)}", f"centre_m = {_toml_value(obj.centre_m)}"]
        for key in sorted(_SHAPES[shape][1]):
            lines.append(f"{key} = {_toml_value(getattr(obj, key))}")
        c = obj.conductivity_S_per_m
        material = "conducting" if math.isinf(c) else "insulating" if c == 0 else c
        lines.append(f"material = {_toml_value(material)}")
        if obj.name:
            lines.append(f"name = {_toml_value(obj.name)}")
        lines.append("")
    for table, values in (settings or {}).items():
        lines.append(f"[{table}]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in values.items()]
        lines.append("")
    return "\n".join(lines)


def save_scene(scene: Scene, path: str | Path, sensor_file: str | None = None, settings: dict | None = None) -> Path:
    """Write a scene file that :func:`load_scene` reads back to the same scene."""
    path = Path(path)
    path.write_text(scene_to_toml(scene, sensor_file, settings))
    return path


def apply_overrides(scene: Scene | None = None, *, sensor=None, pose=None, tank=None, objects=None,
                    unbounded: bool = False) -> Scene:
    """A scene from a scene file with command-line values put over it.

    Parameters
    ----------
    scene : Scene or None
        From ``--scene FILE`` (``None``: build from the flags alone).
    sensor : SensorDescription or str, optional
        A sensor or a preset name / sensor file path.
    pose : Pose or str "X,Y,Z,YAW", optional
    tank : Tank, optional
    objects : sequence of objects, optional
        Replace the file's objects.
    unbounded : bool
        Drop the tank (unbounded water).
    """
    if isinstance(sensor, str):
        sensor = load_sensor(sensor)
    if isinstance(pose, str):
        pose = Pose.parse(pose)
    if scene is None:
        if sensor is None:
            raise ValueError("no sensor: give a scene file or a sensor (preset name or sensor file)")
        scene = Scene(sensor=sensor)
    changes = {}
    if sensor is not None:
        changes["sensor"] = sensor
    if pose is not None:
        changes["pose"] = pose
    if tank is not None:
        changes["tank"] = tank
    if unbounded:
        changes["tank"] = None
    if objects is not None:
        changes["objects"] = tuple(objects)
    return replace(scene, **changes)
