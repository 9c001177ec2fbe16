"""Contact impedance of the electrodes as series resistances of the PSM.

With a contact impedance z_c (ohm m^2) the current density through an
electrode is ``(V_electrode - phi) / z_c``. For a PSM sphere standing for a
real electrode of area A_k this is, to the model's accuracy, a resistance
``z_c / A_k`` in series with the electrode: ``V = (M + diag(z_c / A)) I``.
The area is that of the real electrode (meshes.sensor geometry):

* end cap: the hemisphere ``2 pi r^2`` plus its cylindrical collar ``2 pi r e``
  (``e`` = how far the cap's extent reaches inwards beyond the hemisphere),
  or, for an extent h shorter than r, the spherical cap ``2 pi r h``
  (Archimedes); both are ``2 pi r h`` with h the axial extent;
* ring: ``2 pi r w``.

Accuracy: to first order in z_c the extra resistance of a real electrode is
``z_c * integral(j^2 dA) / I^2``, which exceeds ``z_c / A`` where the current
crowds at the electrode's edges; for large z_c the current becomes uniform
and ``z_c / A`` is exact. Against the BEM, for the presets in free space,
the series term is 10-20 % below the BEM's extra resistance at
z_c = 1e-3..1e-2 ohm m^2, about 6 % below at 0.1 ohm m^2 and within 1 % at
1-10 ohm m^2 (angels-2 at 0.0354 S/m).

Example
-------
>>> from electrosense.meshes.sensor import preset
>>> s = preset("angels-2")
>>> A = electrode_areas_m2(s)
>>> bool(np.allclose(A, 2 * np.pi * s.radius_m * (s.electrodes[0].x_max_m - s.electrodes[0].x_min_m)))
True
"""
from __future__ import annotations

import numpy as np

from electrosense.meshes.sensor import SensorDescription

__all__ = ["electrode_areas_m2", "series_resistance_ohm", "series_contact"]


def electrode_areas_m2(sensor: SensorDescription) -> np.ndarray:
    """Wetted area (m^2) of each real electrode of ``sensor``, electrode 1 first (a sector: its share of its
    electrode's area, ``w / pi`` of it for half-angle ``w``)."""
    from electrosense.meshes.sensor import sector_azimuths_rad

    r = sensor.radius_m
    areas = []
    for e in sensor.electrodes:
        h = e.x_max_m - e.x_min_m
        if e.kind == "cap":
            cap = min(h, r)  # spherical cap of height h (a hemisphere when h >= r) ...
            collar = max(h - r, 0.0)  # ... plus the cylindrical collar beyond it
            whole = 2 * np.pi * r * cap + 2 * np.pi * r * collar
        else:
            whole = 2 * np.pi * r * h
        share = 1.0 if not e.is_split else sector_azimuths_rad(e, r)[1] / np.pi
        areas.extend([whole * share] * e.sectors)
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


def series_contact(K_S: np.ndarray, series_ohm: np.ndarray) -> np.ndarray:
    """K of the electrodes seen through series resistances (one per electrode): K (1 + Z K)^-1.

    With electrode terminal potentials W and water-side potentials V, the
    currents leaving the electrodes are I = K V = Z^-1 (W - V), hence
    I = K (1 + Z K)^-1 W. This is the lumped (electrode-averaged) model of a
    contact impedance z_c: Z = z_c / area. It keeps K symmetric with zero
    row sums.
    """
    K = np.asarray(K_S, dtype=float)
    Z = np.asarray(series_ohm, dtype=float)
    n = K.shape[-1]
    A = np.eye(n) + Z[..., :, None] * K  # (1 + Z K)
    # K (1 + Z K)^-1 = ((1 + K Z)^-1 K)  ; solve on the transposed system for stability
    return np.linalg.solve(np.swapaxes(A, -1, -2), np.swapaxes(K, -1, -2)).swapaxes(-1, -2)
