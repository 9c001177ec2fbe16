"""Physical effects a real bench adds to the model, and how the virtual bench builds them in.

Each effect is put into the physics where it belongs, not painted on the
result:

===================  ==========================  ==================================================
name                 value                       what the virtual bench does
===================  ==========================  ==================================================
conductivity         relative offset (-0.02,     the true water conductivity is the nominal one
                     or -2%)                     times (1 + offset); the meta keeps the nominal
temperature_drift    K over the whole run        the water warms linearly in time; the conductivity
                                                 follows at 2 %/K; ``temp_C`` logs the temperature
contact_impedance    ohm m^2                     passed to the model (electrode/water interface)
channel_gain         g1,g2,... (one per          each receiver's amplifier multiplies its measured
                     receiver) or one g          current
pose_offset          dx,dy,dz,dyaw (m, rad)      the sensor really sits at the logged pose + offset
water_depth          m                           the true water depth (the meta keeps the nominal)
tank_size            Lx,Ly,Lz (m)                the true inner size of the tank
unmodelled_object    sphere,X,Y,Z,R[,material]   an object in the water that the meta does not
                     or cylinder,X,Y,R,H[,mat]   mention (material: insulating, conducting, S/m)
===================  ==========================  ==================================================

Example
-------
>>> from electrosense.validation.bench.virtual.effects import Effects
>>> e = Effects.parse(["conductivity=-2%", "channel_gain=1.01,0.99,1.0"])
>>> e.conductivity_rel, e.channel_gain
(-0.02, (1.01, 0.99, 1.0))
"""
from __future__ import annotations

from dataclasses import dataclass, fields

from electrosense.meshes.objects import Cylinder, Sphere

__all__ = ["Effects", "EFFECT_NAMES", "TEMPERATURE_COEFFICIENT_PER_K"]

#: Relative change of the conductivity of water per kelvin (about 2 %/K near 20 C).
TEMPERATURE_COEFFICIENT_PER_K = 0.02

EFFECT_NAMES = ("conductivity", "temperature_drift", "contact_impedance", "channel_gain", "pose_offset",
                "water_depth", "tank_size", "unmodelled_object")


def _float(text: str, name: str) -> float:
    t = text.strip()
    scale = 0.01 if t.endswith("%") else 1.0
    try:
        return float(t.rstrip("%")) * scale
    except ValueError:
        raise ValueError(f"effect {name}: {text!r} is not a number") from None


def _floats(text: str, name: str, count: int | None = None) -> tuple[float, ...]:
    values = tuple(_float(v, name) for v in text.split(","))
    if count is not None and len(values) != count:
        raise ValueError(f"effect {name}: expected {count} numbers, got {len(values)} ({text!r})")
    return values


def parse_object(text: str):
    """``sphere,X,Y,Z,R[,material]`` or ``cylinder,X,Y,R,H[,material]`` (tank frame, m)."""
    parts = [p.strip() for p in text.split(",")]
    kind, args = parts[0].lower(), parts[1:]
    try:
        if kind == "sphere" and len(args) in (4, 5):
            x, y, z, r = (float(v) for v in args[:4])
            return Sphere(centre_m=(x, y, z), radius_m=r, conductivity_S_per_m=args[4] if len(args) == 5 else 0.0,
                          name="unmodelled_object")
        if kind == "cylinder" and len(args) in (4, 5):
            x, y, r, h = (float(v) for v in args[:4])
            return Cylinder(centre_m=(x, y, 0.0), radius_m=r, height_m=h,
                            conductivity_S_per_m=args[4] if len(args) == 5 else 0.0, name="unmodelled_object")
    except ValueError as exc:
        raise ValueError(f"effect unmodelled_object {text!r}: {exc}") from None
    raise ValueError(f"effect unmodelled_object {text!r}: expected sphere,X,Y,Z,R[,material] or "
                     f"cylinder,X,Y,R,H[,material]")


@dataclass(frozen=True)
class Effects:
    """The physical effects of a virtual bench run (all off by default)."""

    conductivity_rel: float = 0.0
    temperature_drift_K: float = 0.0
    contact_impedance_ohm_m2: float | None = None
    channel_gain: tuple[float, ...] | None = None
    pose_offset: tuple[float, float, float, float] | None = None
    water_depth_m: float | None = None
    tank_size_m: tuple[float, float, float] | None = None
    unmodelled_object: object = None
    texts: tuple[str, ...] = ()

    @classmethod
    def parse(cls, items) -> "Effects":
        """From ``NAME=VALUE`` strings (see the module docstring)."""
        values, texts = {}, []
        for item in items:
            name, sep, value = item.partition("=")
            name = name.strip().replace("-", "_")
            if not sep or not value:
                raise ValueError(f"effect {item!r}: expected NAME=VALUE")
            if name not in EFFECT_NAMES:
                raise ValueError(f"unknown effect {name!r}; known: {', '.join(EFFECT_NAMES)}")
            if name == "conductivity":
                values["conductivity_rel"] = _float(value, name)
                if values["conductivity_rel"] <= -1:
                    raise ValueError(f"effect conductivity={value}: the water would not conduct")
            elif name == "temperature_drift":
                values["temperature_drift_K"] = _float(value, name)
            elif name == "contact_impedance":
                values["contact_impedance_ohm_m2"] = _float(value, name)
                if values["contact_impedance_ohm_m2"] < 0:
                    raise ValueError("effect contact_impedance must be >= 0 ohm m^2")
            elif name == "channel_gain":
                values["channel_gain"] = _floats(value, name)
            elif name == "pose_offset":
                values["pose_offset"] = _floats(value, name, 4)
            elif name == "water_depth":
                values["water_depth_m"] = _float(value, name)
            elif name == "tank_size":
                values["tank_size_m"] = _floats(value, name, 3)
            elif name == "unmodelled_object":
                values["unmodelled_object"] = parse_object(value)
            texts.append(f"{name}={value}")
        return cls(**values, texts=tuple(texts))

    @property
    def active(self) -> bool:
        return any(getattr(self, f.name) not in (None, 0.0) for f in fields(self) if f.name != "texts")

    def describe(self) -> str:
        return ", ".join(self.texts) if self.texts else "none"
