"""Contact impedance of the electrodes as series resistances of the PSM.

With a contact impedance z_c (ohm m^2) the current density through an
electrode is ``(V_electrode - phi) / z_c``. For a PSM sphere standing for a
real electrode of area A_k this is, to the model's accuracy, a resistance
``z_c / A_k`` in series with the electrode: ``V = (M + diag(z_c / A)) I``.
The area is that of the real electrode (meshes.sensor geometry):

* end cap: the hemisphere ``2 pi r^2`` plus its cylindrical collar ``2 pi r e``
  (``e`` = how far the cap's extent reaches inwards beyond the hemisphere);
* ring: ``2 pi r w``.

Accuracy: to first order in z_c the extra resistance of a real electrode is
``z_c * integral(j^2 dA) / I^2``, which exceeds ``z_c / A`` where the current
crowds at the electrode's edges; for large z_c the current becomes uniform
and ``z_c / A`` is exact. Against the BEM, for the presets in free space,
the series term is 10-15 % below the BEM's extra resistance at
z_c = 1e-3..1e-2 ohm m^2 and within 2-4 % at 0.1 ohm m^2.

Example
-------
>>> from meshes.sensor import preset
>>> A = electrode_areas_m2(preset("angels-2"))
>>> bool(np.allclose(A, 2 * np.pi * 0.01**2))
True
"""
from __future__ import annotations

import numpy as np

from meshes.sensor import SensorDescription

__all__ = ["electrode_areas_m2", "series_resistance_ohm"]


def electrode_areas_m2(sensor: SensorDescription) -> np.ndarray:
    """Wetted area (m^2) of each real electrode of ``sensor``, electrode 1 first."""
    r = sensor.radius_m
    areas = []
    for e in sensor.electrodes:
        width = e.x_max_m - e.x_min_m
        if e.kind == "cap":
            collar = max(width - r, 0.0)
            areas.append(2 * np.pi * r**2 + 2 * np.pi * r * collar)
        else:
            areas.append(2 * np.pi * r * width)
    return np.array(areas)


def series_resistance_ohm(contact_impedance_ohm_m2, areas_m2) -> np.ndarray:
    """``z_c / A_k`` (ohm) for a scalar or per-electrode ``z_c`` (ohm m^2)."""
    A = np.asarray(areas_m2, dtype=float)
    z = np.broadcast_to(np.asarray(contact_impedance_ohm_m2, dtype=float), A.shape) if np.ndim(contact_impedance_ohm_m2) == 0 \
        else np.asarray(contact_impedance_ohm_m2, dtype=float)
    if z.shape != A.shape:
        raise ValueError(f"contact impedance: expected a scalar or {A.size} values (one per electrode), got {z.size}")
    if not np.all(np.isfinite(z)) or np.any(z < 0):
        raise ValueError(f"contact impedance must be finite and >= 0 ohm m^2, got {z.tolist()}")
    return z / A
