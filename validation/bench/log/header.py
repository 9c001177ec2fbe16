"""The header of a bench log (version 1): format line, meta line, column row.

See the bench-log format (version 1), ``docs/bench-log.md``: line 1 is exactly
``# esense-bench-log 1``, line 2 is ``# meta: `` and one JSON object, more
``#`` comment lines may follow, then the column row. This module turns that
text into checked Python objects, and back; the reader and the writer share it
so that the writer never produces what the reader would refuse.

Example
-------
>>> from electrosense.validation.bench.log.header import interpret_meta, receiver_columns
>>> h = interpret_meta({"sensor": "angels-4", "emitter": 4, "tank_m": [1, 1, 1],
...                     "sigma_S_per_m": 0.0354}, file="run.csv")
>>> receiver_columns(h.sensor)
('I1_A', 'I2_A', 'I3_A')
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from electrosense.meshes.cylinder_tank import CylinderTank
from electrosense.meshes.objects import Box, Cylinder, Sphere
from electrosense.meshes.sensor import SensorDescription, load_sensor
from electrosense.meshes.tank import Tank
from electrosense.validation.bench.log.errors import BenchLogError

__all__ = [
    "FORMAT_LINE", "META_PREFIX", "REQUIRED_META_KEYS", "BASE_COLUMNS", "OPTIONAL_NUMERIC_COLUMNS",
    "PASS_COLUMN", "Header", "receiver_columns", "standard_columns", "parse_format_line", "parse_meta_line",
    "interpret_meta", "check_columns", "format_meta_line", "META_LINE", "same_run", "tank_meta", "describe_tank",
    "logged_objects", "objects_meta",
]

FORMAT_VERSION = 1
FORMAT_LINE = f"# esense-bench-log {FORMAT_VERSION}"
META_PREFIX = "# meta: "
META_LINE = 2
REQUIRED_META_KEYS = ("sensor", "emitter", "tank_m", "sigma_S_per_m")
NUMERIC_META_KEYS = ("water_depth_m", "temperature_C", "voltage_V")
#: the optional meta key of a vertical cylindrical tank (``tank_m`` is then its bounding box)
CYLINDER_META_KEY = "tank_cylinder"
CYLINDER_KEYS = ("radius_m", "floor_radius_m")
#: relative tolerance of the check that ``tank_m`` is a cylinder's bounding box (a logger's rounding passes)
BOUNDING_BOX_REL_TOL = 1e-6
#: the optional meta key of the fixed objects known to be in the tank (``esense sweep`` of a scene writes it)
OBJECTS_META_KEY = "objects"
_OBJECT_SHAPES = {"sphere": Sphere, "box": Box, "cylinder": Cylinder}
BASE_COLUMNS = ("t_s", "x_m", "y_m", "z_m", "yaw_rad", "U_V")
OPTIONAL_NUMERIC_COLUMNS = ("temp_C", "sigma_S_per_m")
PASS_COLUMN = "pass"
_RECEIVER_COLUMN = re.compile(r"I(\d+)_A")


@dataclass(frozen=True)
class Header:
    """What the meta line says, checked and interpreted.

    ``meta`` is the JSON object exactly as read (unknown keys kept);
    ``sensor`` carries the emitter of the meta line.
    """

    meta: dict
    sensor: SensorDescription
    tank: Tank | CylinderTank | None
    sigma_S_per_m: float
    emitter: int


def receiver_columns(sensor: SensorDescription) -> tuple[str, ...]:
    """Current columns ``I<k>_A`` for every receiver, in electrode order."""
    return tuple(f"I{k}_A" for k in sensor.receivers)


def standard_columns(sensor: SensorDescription, temperature: bool = False, passes: bool = False) -> tuple[str, ...]:
    """The spec's columns for ``sensor``: pose, voltage, receiver currents (and optional ones)."""
    cols = BASE_COLUMNS + receiver_columns(sensor)
    if temperature:
        cols += ("temp_C",)
    if passes:
        cols += (PASS_COLUMN,)
    return cols


def parse_format_line(text: str, file) -> None:
    """Refuse anything but ``# esense-bench-log 1`` as line 1, saying what differs."""
    if text == FORMAT_LINE:
        return
    if text.startswith("\ufeff"):
        raise BenchLogError(file, 1, "line 1 starts with a UTF-8 byte-order mark (BOM); save the file as UTF-8 "
                                     "without a BOM")
    m = re.fullmatch(r"#\s*esense-bench-log\s+(\S+)\s*", text)
    if m and m.group(1) != str(FORMAT_VERSION):
        raise BenchLogError(
            file, 1, f"unsupported bench-log version {m.group(1)!r}: this reader knows version {FORMAT_VERSION} "
            f"(line 1 must be exactly {FORMAT_LINE!r})"
        )
    if text.strip() == FORMAT_LINE:
        raise BenchLogError(file, 1, f"line 1 has white space around {FORMAT_LINE!r} (found {text!r}); it must be "
                                     "exactly that text, with no trailing space")
    if m:
        raise BenchLogError(file, 1, f"line 1 is spaced differently from {FORMAT_LINE!r} (found {text!r}); it must "
                                     "be exactly that text")
    raise BenchLogError(file, 1, f"not a bench log: line 1 must be exactly {FORMAT_LINE!r}, found {text[:60]!r}")


def _unique_keys(pairs: list[tuple[str, object]]) -> dict:
    """A JSON object's pairs as a dict, refusing a key given twice (json would keep the last one silently)."""
    out = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"the key {key!r} appears twice (a reader would have to choose one value)")
        out[key] = value
    return out


def _refuse_constant(name: str):
    raise ValueError(f"{name} is not valid JSON")


def parse_meta_line(text: str, file, line: int = META_LINE) -> dict:
    """The JSON object of a ``# meta: {...}`` line (NaN and Infinity refused)."""
    if not text.startswith(META_PREFIX):
        raise BenchLogError(file, line, f"line 2 must start with {META_PREFIX!r} and hold one JSON object, found {text[:60]!r}")
    try:
        meta = json.loads(text[len(META_PREFIX):], parse_constant=_refuse_constant, object_pairs_hook=_unique_keys)
    except (json.JSONDecodeError, ValueError) as exc:
        raise BenchLogError(file, line, f"bad JSON in the meta line: {exc}") from None
    if not isinstance(meta, dict):
        raise BenchLogError(file, line, f"the meta line must hold a JSON object, found a {type(meta).__name__}")
    return meta


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def interpret_meta(meta: dict, file, folder: str | Path | None = None, line: int = META_LINE) -> Header:
    """Check the meta object and build the sensor, the tank and the nominal conductivity.

    ``sensor`` is a preset name or a path relative to ``folder`` (the log's folder).
    """
    missing = [k for k in REQUIRED_META_KEYS if k not in meta]
    if missing:
        raise BenchLogError(
            file, line, f"the meta line lacks the required key{'s' if len(missing) > 1 else ''} "
            f"{', '.join(repr(k) for k in missing)} (required: {', '.join(REQUIRED_META_KEYS)})"
        )
    spec = meta["sensor"]
    if not isinstance(spec, str) or not spec:
        raise BenchLogError(file, line, f"meta 'sensor' must be a preset name or a file path, found {spec!r}")
    try:
        sensor = load_sensor(spec, relative_to=folder)
    except ValueError as exc:
        raise BenchLogError(file, line, f"meta 'sensor': {exc}") from None

    emitter = meta["emitter"]
    if not isinstance(emitter, int) or isinstance(emitter, bool):
        raise BenchLogError(file, line, f"meta 'emitter' must be an integer electrode number, found {emitter!r}")
    if not 1 <= emitter <= sensor.n_electrodes:
        raise BenchLogError(
            file, line, f"meta 'emitter' {emitter} is not an electrode of {spec} (1..{sensor.n_electrodes})"
        )
    sensor = sensor.with_emitter(emitter)

    for key in NUMERIC_META_KEYS:
        if key in meta and not _number(meta[key]):
            raise BenchLogError(file, line, f"meta {key!r} must be a finite number, found {meta[key]!r}")

    tank = _interpret_tank(meta, file, line)
    logged_objects(meta, file, line)   # refused here, at the read, if malformed

    sigma = meta["sigma_S_per_m"]
    if not (_number(sigma) and sigma > 0):
        raise BenchLogError(file, line, f"meta 'sigma_S_per_m' must be a positive number (S/m), found {sigma!r}")
    return Header(meta=meta, sensor=sensor, tank=tank, sigma_S_per_m=float(sigma), emitter=emitter)


def _interpret_tank(meta: dict, file, line: int) -> Tank | CylinderTank | None:
    """The tank of the meta line: a box ``tank_m``, a cylinder ``tank_cylinder`` in its bounding box, or None."""
    tank_m = meta["tank_m"]
    cylinder = meta.get(CYLINDER_META_KEY)
    if tank_m is None:
        if "water_depth_m" in meta:
            raise BenchLogError(file, line, "meta 'water_depth_m' is given but 'tank_m' is null (unbounded water)")
        if cylinder is not None:
            raise BenchLogError(file, line, f"meta {CYLINDER_META_KEY!r} is given but 'tank_m' is null (unbounded "
                                            "water); give the cylinder's bounding box [2R, 2R, height] as 'tank_m'")
        return None
    if not (isinstance(tank_m, list) and len(tank_m) == 3 and all(_number(v) and v > 0 for v in tank_m)):
        raise BenchLogError(
            file, line, f"meta 'tank_m' must be [Lx, Ly, Lz] (three positive lengths in m) or null, found {tank_m!r}"
        )
    size = tuple(float(v) for v in tank_m)
    if cylinder is None:
        try:
            return Tank(size, meta.get("water_depth_m"))
        except ValueError as exc:
            raise BenchLogError(file, line, f"meta: {exc}") from None
    where = f"meta {CYLINDER_META_KEY!r}"
    if not isinstance(cylinder, dict):
        raise BenchLogError(file, line, f"{where} must be an object {{\"radius_m\": R, \"floor_radius_m\": Rf}} "
                                        f"(Rf optional), found {cylinder!r}")
    unknown = [k for k in cylinder if k not in CYLINDER_KEYS]
    if unknown or "radius_m" not in cylinder:
        what = f"has unknown key(s) {', '.join(map(repr, unknown))}" if unknown else "lacks 'radius_m'"
        raise BenchLogError(file, line, f"{where} {what} (keys: radius_m, the inner radius at the top, and "
                                        "optionally floor_radius_m, in m)")
    for k, v in cylinder.items():
        if not (_number(v) and v > 0):
            raise BenchLogError(file, line, f"{where}: {k!r} must be a positive length in m, found {v!r}")
    r_top = float(cylinder["radius_m"])
    r_floor = float(cylinder.get("floor_radius_m", r_top))
    box = (2 * max(r_top, r_floor),) * 2
    if not np.allclose(size[:2], box, rtol=BOUNDING_BOX_REL_TOL, atol=0):
        raise BenchLogError(file, line, f"meta 'tank_m' {list(size)} is not the bounding box of the cylinder of "
                                        f"{where} ([{box[0]:g}, {box[1]:g}, height]): the two disagree on the "
                                        "tank's size")
    try:
        return CylinderTank(r_top, size[2], meta.get("water_depth_m"), r_floor)
    except ValueError as exc:
        raise BenchLogError(file, line, f"meta: {exc}") from None


def logged_objects(meta: dict, file="", line: int = META_LINE) -> tuple:
    """The fixed objects of the meta line's ``objects`` list (none where it is absent), checked.

    Each entry is ``{"shape": "sphere" | "box" | "cylinder", "centre_m": [x, y, z], "conductivity_S_per_m": S
    or "conducting" / "insulating", "name": ..., and the shape's sizes}``, as :func:`objects_meta` writes it.

    >>> logged_objects({"objects": [{"shape": "sphere", "centre_m": [0.1, 0, 0], "radius_m": 0.02,
    ...                              "conductivity_S_per_m": "conducting"}]})[0].is_conducting
    True
    """
    entries = meta.get(OBJECTS_META_KEY)
    if entries is None:
        return ()
    if not isinstance(entries, list):
        raise BenchLogError(file, line, f"meta {OBJECTS_META_KEY!r} must be a list of objects, found {entries!r}")
    objects = []
    for i, entry in enumerate(entries, start=1):
        where = f"meta {OBJECTS_META_KEY!r} entry {i}"
        shape = entry.get("shape") if isinstance(entry, dict) else None
        if shape not in _OBJECT_SHAPES:
            raise BenchLogError(file, line, f"{where}: 'shape' must be one of {', '.join(_OBJECT_SHAPES)}, found "
                                            f"{shape!r}")
        cls = _OBJECT_SHAPES[shape]
        allowed = {f.name for f in fields(cls)}
        unknown = sorted(set(entry) - allowed - {"shape"})
        if unknown or "centre_m" not in entry:
            what = f"unknown key(s) {', '.join(map(repr, unknown))}" if unknown else "no 'centre_m'"
            raise BenchLogError(file, line, f"{where} ({shape}) has {what}; keys: {', '.join(sorted(allowed))}")
        for k, n in (("radius_m", 1), ("height_m", 1), ("size_m", 3)):   # the shape's sizes, each given
            if k not in allowed:
                continue
            v = entry.get(k)
            values = v if n > 1 and isinstance(v, list) else [v]
            if len(values) != n or not all(_number(u) and u > 0 for u in values):
                what = "a positive length" if n == 1 else f"{n} positive lengths"
                raise BenchLogError(file, line, f"{where} ({shape}): {k!r} must be {what} in m, found {v!r}")
        try:
            objects.append(cls(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in entry.items()
                                  if k != "shape"}))
        except (TypeError, ValueError) as exc:
            raise BenchLogError(file, line, f"{where} ({shape}): {exc}") from None
    return tuple(objects)


def objects_meta(objects) -> list:
    """The meta line's ``objects`` list of fixed objects (the inverse of :func:`logged_objects`; JSON has no
    infinity: a perfect conductor is written ``"conducting"``)."""
    out = []
    for obj in objects:
        entry = {"shape": type(obj).__name__.lower(),
                 **{k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(obj).items()}}
        if math.isinf(obj.conductivity_S_per_m):
            entry["conductivity_S_per_m"] = "conducting"
        out.append(entry)
    return out


def tank_meta(tank: Tank | CylinderTank | None) -> dict:
    """The meta keys that describe ``tank`` (the inverse of the reader's interpretation).

    A cylinder is written as its bounding box ``tank_m`` and its radii in ``tank_cylinder``, so that a reader
    that knows only boxes still sees its extent.

    >>> tank_meta(CylinderTank(0.22, 0.3, 0.25))
    {'tank_m': [0.44, 0.44, 0.3], 'water_depth_m': 0.25, 'tank_cylinder': {'radius_m': 0.22}}
    >>> tank_meta(None)
    {'tank_m': None}
    """
    if tank is None:
        return {"tank_m": None}
    if isinstance(tank, CylinderTank):
        radii = {"radius_m": tank.radius_m}
        if tank.floor_radius_m != tank.radius_m:
            radii["floor_radius_m"] = tank.floor_radius_m
        d = 2 * max(tank.radius_m, tank.floor_radius_m)
        return {"tank_m": [d, d, tank.height_m], "water_depth_m": tank.water_depth_m, CYLINDER_META_KEY: radii}
    return {"tank_m": [float(v) for v in tank.size_m], "water_depth_m": tank.water_depth_m}


def describe_tank(tank: Tank | CylinderTank | None) -> str:
    """The tank in words, for a report.

    >>> describe_tank(CylinderTank(0.22, 0.3, 0.25))
    'cylindrical tank of radius 0.22 m and height 0.3 m, water depth 0.25 m'
    """
    if tank is None:
        return "unbounded water"
    if isinstance(tank, CylinderTank):
        radius = (f"radius {tank.radius_m:g} m" if tank.floor_radius_m == tank.radius_m else
                  f"radius {tank.radius_m:g} m at the top and {tank.floor_radius_m:g} m at the floor")
        return f"cylindrical tank of {radius} and height {tank.height_m:g} m, water depth {tank.water_depth_m:g} m"
    return f"tank {' x '.join(f'{v:g}' for v in tank.size_m)} m, water depth {tank.water_depth_m:g} m"


def check_columns(columns: list[str] | tuple[str, ...], header: Header, file, line: int) -> None:
    """Refuse a column row that lacks a required column or whose receivers do not match the sensor."""
    empty = [i + 1 for i, c in enumerate(columns) if c == ""]
    if empty:
        raise BenchLogError(file, line, f"column {empty[0]} of the column row has no name")
    seen = set()
    for c in columns:
        if c in seen:
            raise BenchLogError(file, line, f"column {c!r} appears twice in the column row")
        seen.add(c)
    missing = [c for c in BASE_COLUMNS if c not in seen]
    if missing:
        raise BenchLogError(file, line, f"missing required column{'s' if len(missing) > 1 else ''} {', '.join(missing)}")
    expected = receiver_columns(header.sensor)
    found = [c for c in columns if _RECEIVER_COLUMN.fullmatch(c)]
    who = f"sensor {header.meta['sensor']} with emitter {header.emitter}"
    if len(found) != len(expected):
        raise BenchLogError(
            file, line, f"receiver column count {len(found)} ({', '.join(found) or 'none'}) does not match the "
            f"{who}: {len(expected)} receivers ({', '.join(expected)})"
        )
    absent = [c for c in expected if c not in seen]
    if absent:
        raise BenchLogError(
            file, line, f"missing receiver column{'s' if len(absent) > 1 else ''} {', '.join(absent)} for the {who} "
            f"(found {', '.join(found)})"
        )


def format_meta_line(meta: dict) -> str:
    """``# meta: {...}`` on one line (no NaN, no line breaks)."""
    try:
        text = json.dumps(meta, allow_nan=False, ensure_ascii=False)
    except ValueError as exc:
        raise ValueError(f"meta cannot be written as JSON: {exc}") from None
    return META_PREFIX + text


def same_run(a: Header, b: Header) -> list[str]:
    """Meta keys on which two headers disagree (those that fix the physics of a run)."""
    keys = ("sensor", "emitter", "tank_m", CYLINDER_META_KEY, "sigma_S_per_m")
    differ = [k for k in keys if a.meta.get(k) != b.meta.get(k)]
    if (a.tank and a.tank.water_depth_m) != (b.tank and b.tank.water_depth_m):
        differ.append("water_depth_m")
    return differ
