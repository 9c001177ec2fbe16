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
from dataclasses import dataclass
from pathlib import Path

from electrosense.meshes.sensor import SensorDescription, load_sensor
from electrosense.meshes.tank import Tank
from electrosense.validation.bench.log.errors import BenchLogError

__all__ = [
    "FORMAT_LINE", "META_PREFIX", "REQUIRED_META_KEYS", "BASE_COLUMNS", "OPTIONAL_NUMERIC_COLUMNS",
    "PASS_COLUMN", "Header", "receiver_columns", "standard_columns", "parse_format_line", "parse_meta_line",
    "interpret_meta", "check_columns", "format_meta_line", "META_LINE", "same_run",
]

FORMAT_VERSION = 1
FORMAT_LINE = f"# esense-bench-log {FORMAT_VERSION}"
META_PREFIX = "# meta: "
META_LINE = 2
REQUIRED_META_KEYS = ("sensor", "emitter", "tank_m", "sigma_S_per_m")
NUMERIC_META_KEYS = ("water_depth_m", "temperature_C", "voltage_V")
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
    tank: Tank | None
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

    tank_m = meta["tank_m"]
    if tank_m is None:
        if "water_depth_m" in meta:
            raise BenchLogError(file, line, "meta 'water_depth_m' is given but 'tank_m' is null (unbounded water)")
        tank = None
    else:
        if not (isinstance(tank_m, list) and len(tank_m) == 3 and all(_number(v) and v > 0 for v in tank_m)):
            raise BenchLogError(
                file, line, f"meta 'tank_m' must be [Lx, Ly, Lz] (three positive lengths in m) or null, found {tank_m!r}"
            )
        try:
            tank = Tank(tuple(float(v) for v in tank_m), meta.get("water_depth_m"))
        except ValueError as exc:
            raise BenchLogError(file, line, f"meta: {exc}") from None

    sigma = meta["sigma_S_per_m"]
    if not (_number(sigma) and sigma > 0):
        raise BenchLogError(file, line, f"meta 'sigma_S_per_m' must be a positive number (S/m), found {sigma!r}")
    return Header(meta=meta, sensor=sensor, tank=tank, sigma_S_per_m=float(sigma), emitter=emitter)


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
    keys = ("sensor", "emitter", "tank_m", "sigma_S_per_m")
    differ = [k for k in keys if a.meta.get(k) != b.meta.get(k)]
    if (a.tank and a.tank.water_depth_m) != (b.tank and b.tank.water_depth_m):
        differ.append("water_depth_m")
    return differ
