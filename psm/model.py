"""The poly-spherical model: n spherical electrodes in the sensor frame, saved as JSON.

Sensor frame as in :mod:`electrosense.meshes.sensor`: x along the axis, electrode 1 at the
head (+x), the emitter the last electrode by default.

Example
-------
>>> m = PolySphericalModel.collinear(radii_m=[0.0072, 0.0072], gaps_m=[0.2])
>>> m.centres_m[:, 0].tolist(), m.emitter
([0.1, -0.1], 2)
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["PolySphericalModel", "ModelError"]


class ModelError(ValueError):
    """An impossible poly-spherical model (overlapping spheres, bad radii...)."""


@dataclass(frozen=True, eq=False)
class PolySphericalModel:
    """n spheres (radii, centres in the sensor frame) with an emitter.

    Parameters
    ----------
    radii_m : (n,) array
        Sphere radii (m).
    centres_m : (n, 3) array
        Sphere centres in the sensor frame (m), electrode 1 at the head (+x).
    emitter : int
        1-based emitter number (0: the last electrode).
    gamma_criterion : float or None
        The paper's criterion (17) reached by the calibration that made the model.
    reference : dict or None
        The reference the model was fitted to (``ConductanceMatrix.to_json_dict()``).
    electrode_areas_m2 : (n,) array or None
        Areas of the matching real electrodes, for the contact impedance
        (:mod:`electrosense.psm.contact`).
    info : dict
        Free-form provenance (sensor name, fit parameters and uncertainties...).
    """

    radii_m: np.ndarray
    centres_m: np.ndarray
    emitter: int = 0
    gamma_criterion: float | None = None
    reference: dict | None = None
    electrode_areas_m2: np.ndarray | None = None
    info: dict = field(default_factory=dict, compare=False)

    def __post_init__(self):
        a = np.asarray(self.radii_m, dtype=float).reshape(-1)
        c = np.asarray(self.centres_m, dtype=float)
        n = a.size
        if n < 2:
            raise ModelError(f"a poly-spherical model needs at least 2 spheres, got {n}")
        if c.shape != (n, 3):
            raise ModelError(f"centres_m must be ({n}, 3) for {n} radii, got shape {c.shape}")
        if not (np.all(np.isfinite(a)) and np.all(a > 0)):
            raise ModelError(f"radii_m must be positive and finite, got {a.tolist()}")
        if not np.all(np.isfinite(c)):
            raise ModelError("centres_m contains non-finite values")
        emitter = n if self.emitter == 0 else int(self.emitter)
        if not 1 <= emitter <= n:
            raise ModelError(f"emitter {self.emitter} is not an electrode number 1..{n}")
        for p in range(n):
            for q in range(p + 1, n):
                d = float(np.linalg.norm(c[p] - c[q]))
                if d <= a[p] + a[q]:
                    raise ModelError(
                        f"spheres {p + 1} and {q + 1} overlap: centre distance {d * 1e3:.3f} mm "
                        f"<= radii sum {(a[p] + a[q]) * 1e3:.3f} mm"
                    )
        object.__setattr__(self, "radii_m", a)
        object.__setattr__(self, "centres_m", c)
        object.__setattr__(self, "emitter", emitter)
        if self.electrode_areas_m2 is not None:
            A = np.asarray(self.electrode_areas_m2, dtype=float).reshape(-1)
            if A.size != n or not np.all(A > 0):
                raise ModelError(f"electrode_areas_m2 must be {n} positive areas, got {A.tolist()}")
            object.__setattr__(self, "electrode_areas_m2", A)

    def __eq__(self, other) -> bool:
        if not isinstance(other, PolySphericalModel):
            return NotImplemented
        areas = (self.electrode_areas_m2 is None and other.electrode_areas_m2 is None) or (
            self.electrode_areas_m2 is not None and other.electrode_areas_m2 is not None
            and np.array_equal(self.electrode_areas_m2, other.electrode_areas_m2))
        return (np.array_equal(self.radii_m, other.radii_m) and np.array_equal(self.centres_m, other.centres_m)
                and self.emitter == other.emitter and self.gamma_criterion == other.gamma_criterion
                and self.reference == other.reference and areas)

    __hash__ = None

    # ----------------------------------------------------------------- derived
    @property
    def n(self) -> int:
        return self.radii_m.size

    @property
    def receivers(self) -> tuple[int, ...]:
        return tuple(k for k in range(1, self.n + 1) if k != self.emitter)

    @property
    def length_m(self) -> float:
        """Distance between the two outermost sphere centres."""
        d = np.linalg.norm(self.centres_m[:, None] - self.centres_m[None], axis=-1)
        return float(d.max())

    @classmethod
    def collinear(cls, radii_m, gaps_m, emitter: int = 0, **kwargs) -> "PolySphericalModel":
        """Spheres on the x axis, centred on the origin, head (+x) first.

        ``gaps_m[k]`` is the centre distance between electrodes k+1 and k+2.
        """
        gaps = np.asarray(gaps_m, dtype=float).reshape(-1)
        x = np.concatenate([[0.0], -np.cumsum(gaps)])
        x -= 0.5 * (x[0] + x[-1])
        c = np.zeros((x.size, 3))
        c[:, 0] = x
        return cls(np.asarray(radii_m, dtype=float), c, emitter, **kwargs)

    # -------------------------------------------------------------------- JSON
    def to_json_dict(self) -> dict:
        d = {
            "model": "poly-spherical",
            "convention": "sensor frame: x along the axis, electrode 1 at the head (+x); emitter 1-based; SI units",
            "radii_m": self.radii_m.tolist(),
            "centres_m": self.centres_m.tolist(),
            "emitter": self.emitter,
            "gamma_criterion": self.gamma_criterion,
            "reference": self.reference,
        }
        if self.electrode_areas_m2 is not None:
            d["electrode_areas_m2"] = self.electrode_areas_m2.tolist()
        if self.info:
            d["info"] = self.info
        return d

    @classmethod
    def from_json_dict(cls, d: dict) -> "PolySphericalModel":
        try:
            return cls(
                radii_m=d["radii_m"],
                centres_m=d["centres_m"],
                emitter=int(d.get("emitter", 0)),
                gamma_criterion=d.get("gamma_criterion"),
                reference=d.get("reference"),
                electrode_areas_m2=d.get("electrode_areas_m2"),
                info=d.get("info", {}),
            )
        except KeyError as exc:
            raise ModelError(f"PSM JSON lacks the key {exc}") from None

    def save(self, path: str | Path) -> None:
        """Write the model as JSON (keys ``radii_m``, ``centres_m``, ``emitter``, ``gamma_criterion``, ``reference``)."""
        Path(path).write_text(json.dumps(self.to_json_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> "PolySphericalModel":
        path = Path(path)
        try:
            d = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise ModelError(f"{path}: not valid JSON: {exc}") from None
        try:
            return cls.from_json_dict(d)
        except ModelError as exc:
            raise ModelError(f"{path}: {exc}") from None
