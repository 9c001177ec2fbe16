"""Parsers of command-line values shared by several ``esense`` subcommands."""
from __future__ import annotations

import click


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
