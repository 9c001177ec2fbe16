"""Parsers of command-line values shared by several ``esense`` subcommands."""
from __future__ import annotations

import math

import click


class _FiniteFloat(click.ParamType):
    """A float that is finite (no inf, no nan), and positive when asked; errors name the option as typed."""

    name = "number"

    def __init__(self, positive: bool = False):
        self.positive = positive

    def convert(self, value, param, ctx):
        if isinstance(value, float) and math.isfinite(value) and (value > 0 or not self.positive):
            return value
        try:
            x = float(value)
        except (TypeError, ValueError):
            self.fail(f"{value!r} is not a number", param, ctx)
        if not math.isfinite(x):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        if self.positive and not x > 0:
            self.fail(f"{value!r}: must be positive", param, ctx)
        return x


def finite_float(positive: bool = False) -> click.ParamType:
    """A click type for a finite float (``positive``: > 0), refusing ``inf``, ``nan`` (and ``<= 0``).

    >>> finite_float(positive=True).convert("0.5", None, None)
    0.5
    """
    return _FiniteFloat(positive)


def parse_tank(text: str, param_hint: str = "--tank"):
    """``"LX,LY,LZ"`` (m) as a :class:`meshes.tank.Tank`, or a click error naming the option."""
    from meshes.tank import Tank

    try:
        size = [float(v) for v in text.split(",")]
    except ValueError:
        raise click.BadParameter(f"{text!r}: expected LX,LY,LZ in metres", param_hint=param_hint) from None
    if len(size) != 3:
        raise click.BadParameter(f"{text!r}: expected three lengths LX,LY,LZ (m)", param_hint=param_hint)
    try:
        return Tank(tuple(size))
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint=param_hint) from None


def check_edge_length(sensor, edge_length_m: float | None, param_hint: str = "--edge-length") -> None:
    """Refuse, before meshing, an edge length that is not positive or would make too many triangles.

    The count is estimated from the sensor's geometry (:func:`meshes.sensor_mesh.estimate_triangles`).
    """
    if edge_length_m is None:
        return
    from meshes.sensor_mesh import MAX_SENSOR_TRIANGLES, estimate_triangles

    if not (math.isfinite(edge_length_m) and edge_length_m > 0):
        raise click.BadParameter(f"must be a positive length in metres, got {edge_length_m}", param_hint=param_hint)
    try:
        n = estimate_triangles(sensor, edge_length_m)
    except ValueError as exc:
        raise click.BadParameter(str(exc).removeprefix("mesh_sensor: "), param_hint=param_hint) from None
    if n > MAX_SENSOR_TRIANGLES:
        raise click.BadParameter(
            f"{edge_length_m:g} m would mesh {sensor.name or 'the sensor'} with about {n:,} triangles (at most "
            f"{MAX_SENSOR_TRIANGLES:,}; a dense BEM needs 8 N^2 bytes): choose a larger edge length",
            param_hint=param_hint,
        )
