"""Contact impedance as the BEM's boundary condition, in the diagnosis's lumped form: effective areas.

The diagnosis applies a contact impedance z_c to a baseline K as series
resistances z_c / A_k (:func:`electrosense.psm.contact.series_contact`).
With the electrode's geometric area A_k that is 10-20 % off the BEM, whose
boundary condition sees the current crowd at the electrode's edges
(:mod:`electrosense.psm.contact`). Here the areas are replaced by *effective* areas
A_k(z_c), fitted so that the lumped network reproduces the BEM with the
contact boundary condition for the sensor alone in unbounded water (ring
elements on the meridian, :func:`electrosense.bem.meridian.meridian_conductance`: exact
for a sensor of revolution, about a second a solve) on a grid of z_c; between
grid values A_k is interpolated in log z_c. The environment changes the
water's resistance but hardly the distribution of the current over an
electrode's surface, which is what the effective area carries.

Example
-------
>>> from electrosense.meshes.sensor import preset
>>> ea = effective_areas(preset("angels-2"), 0.0354)
>>> from electrosense.psm.contact import electrode_areas_m2
>>> bool(np.all(ea(1e-3) < electrode_areas_m2(preset("angels-2"))))   # crowding at the edges: smaller
True
"""
from __future__ import annotations

import functools
import json
from dataclasses import dataclass

import numpy as np

from electrosense.meshes.sensor import SensorDescription
from electrosense.psm.contact import electrode_areas_m2

__all__ = ["EffectiveAreas", "effective_areas", "Z_GRID_OHM_M2"]

#: contact impedances (ohm m^2) at which the BEM is solved
Z_GRID_OHM_M2 = np.array([1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1.0])  # beyond 1 ohm m^2 the areas are geometric to 1 %


@dataclass(frozen=True)
class EffectiveAreas:
    """A_k(z_c) (m^2): the lumped series z_c / A_k that reproduces the BEM's boundary condition."""

    z_grid_ohm_m2: np.ndarray
    areas_m2: np.ndarray  # (Z, n)
    geometric_m2: np.ndarray  # (n,)
    fit_error: np.ndarray  # (Z,) max relative error of the lumped network against the BEM at each grid z

    def __call__(self, z_ohm_m2) -> np.ndarray:
        """Effective areas (n,) for contact impedances ``z_ohm_m2`` (scalar or (n,), one per electrode)."""
        z = np.broadcast_to(np.asarray(z_ohm_m2, float), self.geometric_m2.shape)
        lz = np.log(np.clip(z, self.z_grid_ohm_m2[0], self.z_grid_ohm_m2[-1]))
        lg = np.log(self.z_grid_ohm_m2)
        return np.array([np.interp(lz[k], lg, self.areas_m2[:, k]) for k in range(len(z))])


#: weight of the pull of log(A / A_geometric) towards zero in the areas' fit: a sensor of n electrodes has
#: n (n - 1) / 2 transfer conductances for n areas, so that two electrodes (one conductance) leave one
#: direction open, which this closes (the smallest change of the geometric areas that fits); far below the
#: fit's residuals elsewhere
AREA_PRIOR_WEIGHT = 1e-4


def _fit_areas(K0, Kz, z, A0):
    from scipy.optimize import least_squares

    from electrosense.validation.diagnosis.forward import series_contact

    n = K0.shape[0]
    off = ~np.eye(n, dtype=bool)
    log_A0 = np.log(A0)

    def res(logA):
        return (series_contact(K0, z / np.exp(logA))[off] / Kz[off]) - 1.0

    def res_with_prior(logA):
        return np.concatenate([res(logA), AREA_PRIOR_WEIGHT * (logA - log_A0)])

    sol = least_squares(res_with_prior, log_A0, method="lm")
    return np.exp(sol.x), float(np.max(np.abs(res(sol.x))))


def _disk_path(sensor_json: str, sigma_S_per_m: float):
    """The file of the effective areas of one sensor geometry (its name left out) at one conductivity, keyed as
    well by the model code's version (:func:`electrosense.validation.simulation.models.code_version`)."""
    import hashlib

    from electrosense.validation.diagnosis.anchored import anchor_cache_dir
    from electrosense.validation.simulation.models import code_version

    geometry = {k: v for k, v in json.loads(sensor_json).items() if k not in ("name", "notes")}
    text = json.dumps({"sensor": geometry, "sigma": repr(float(sigma_S_per_m)), "z": Z_GRID_OHM_M2.tolist(),
                       "code": code_version()}, sort_keys=True)
    return anchor_cache_dir().parent / "diagnosis-contact" / f"{hashlib.sha256(text.encode()).hexdigest()[:24]}.npz"


@functools.lru_cache(maxsize=16)
def _cached(sensor_json: str, sigma_S_per_m: float) -> EffectiveAreas:
    """Computed once per sensor and conductivity, kept on disk (7 meridian BEM solves on one assembly)."""
    import os

    path = _disk_path(sensor_json, sigma_S_per_m)
    try:
        with np.load(path) as z:
            return EffectiveAreas(z["z_grid_ohm_m2"], z["areas_m2"], z["geometric_m2"], z["fit_error"])
    except (OSError, ValueError, KeyError, EOFError):
        pass
    out = _compute(sensor_json, sigma_S_per_m)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        partial = path.with_name(f"{path.stem}.{os.getpid()}.partial.npz")
        np.savez(partial, z_grid_ohm_m2=out.z_grid_ohm_m2, areas_m2=out.areas_m2, geometric_m2=out.geometric_m2,
                 fit_error=out.fit_error)
        os.replace(partial, path)
    except OSError:  # not cached: computed again next time
        pass
    return out


def _compute(sensor_json: str, sigma_S_per_m: float) -> EffectiveAreas:
    from electrosense.bem.meridian import layer_operators, meridian_conductance, mesh_meridian

    sensor = SensorDescription.from_dict(json.loads(sensor_json))
    A0 = electrode_areas_m2(sensor)
    mesh = mesh_meridian(sensor)
    operators = layer_operators(mesh)   # the same for every contact impedance
    K0 = meridian_conductance(sensor, sigma_S_per_m, mesh=mesh, operators=operators).K_S
    areas, errors = [], []
    for z in Z_GRID_OHM_M2:
        Kz = meridian_conductance(sensor, sigma_S_per_m, contact_impedance_ohm_m2=float(z), mesh=mesh,
                                  operators=operators).K_S
        A, e = _fit_areas(K0, Kz, float(z), areas[-1] if areas else A0)
        areas.append(A)
        errors.append(e)
    return EffectiveAreas(Z_GRID_OHM_M2.copy(), np.array(areas), A0, np.array(errors))


def effective_areas(sensor: SensorDescription, sigma_S_per_m: float) -> EffectiveAreas:
    """:class:`EffectiveAreas` of ``sensor`` at ``sigma_S_per_m`` (computed once per process)."""
    return _cached(json.dumps(sensor.to_dict(), sort_keys=True), float(sigma_S_per_m))
