"""The ``--meta`` text of ``esense acquire``: ``key=value`` pairs separated by commas.

A value may itself hold commas (``tank=1,1,1``): a piece without ``=``
belongs to the value before it. Short names are accepted for the usual keys
(``tank`` for ``tank_m``, ``sigma`` for ``sigma_S_per_m``, ``depth`` for
``water_depth_m``, ``temperature`` for ``temperature_C``, ``voltage`` for
``voltage_V``); numbers become numbers, ``none``/``null`` becomes null.

Example
-------
>>> parse_meta_option("sensor=angels-4,emitter=4,tank=1,1,1,sigma=0.0354")
{'sensor': 'angels-4', 'emitter': 4, 'tank_m': [1.0, 1.0, 1.0], 'sigma_S_per_m': 0.0354}
"""
from __future__ import annotations

__all__ = ["parse_meta_option", "ALIASES"]

ALIASES = {"tank": "tank_m", "sigma": "sigma_S_per_m", "depth": "water_depth_m", "water_depth": "water_depth_m",
           "temperature": "temperature_C", "voltage": "voltage_V"}


def _value(text: str):
    t = text.strip()
    if t.lower() in ("none", "null"):
        return None
    try:
        return int(t)
    except ValueError:
        pass
    try:
        return float(t)
    except ValueError:
        return t


def parse_meta_option(text: str) -> dict:
    """``key=value,...`` as a meta dict (see the module docstring)."""
    pairs: list[tuple[str, list[str]]] = []
    for piece in text.split(","):
        if "=" in piece:
            key, _, value = piece.partition("=")
            key = key.strip()
            if not key:
                raise ValueError(f"--meta {text!r}: a piece {piece!r} has no key")
            pairs.append((ALIASES.get(key, key), [value]))
        elif pairs:
            pairs[-1][1].append(piece)
        else:
            raise ValueError(f"--meta {text!r}: expected key=value pairs, e.g. sensor=angels-4,emitter=4")
    meta = {}
    for key, values in pairs:
        if key == "tank_m":
            if len(values) == 1 and _value(values[0]) is None:
                meta[key] = None
                continue
            if len(values) != 3:
                raise ValueError(f"--meta: tank needs three lengths Lx,Ly,Lz (m) or none, got {','.join(values)}")
            try:
                meta[key] = [float(v) for v in values]
            except ValueError:
                raise ValueError(f"--meta: tank {','.join(values)} must be numbers (m)") from None
        else:
            meta[key] = _value(values[0]) if len(values) == 1 else ",".join(values)
    return meta
