"""An unmodelled object's change of K from the BEM's own field where it sits (dipole and quadrupole).

The object candidate is a sphere at ``p``. Its change of K, to the first
two orders of its size, is the mutual energy of the sensor's isolated unit
solutions at ``p`` (:mod:`electrosense.bem.free_field`)::

    dK_ij = sigma (d1 grad u_i . grad u_j + d2 H_i : H_j),

with ``d1``, ``d2`` the sphere's dipole and quadrupole factors
(:func:`~electrosense.bem.free_field.sphere_multipole_factors`). The field is the BEM's in
unbounded water (tabulated once per sensor over its meridian half-plane,
so that the body's shadow and the electrodes' true extent are in it; the
point-electrode model's Kelvin images have neither), and the tank's walls
add their mirror images: at a point ``p`` of a box the field of the sensor
is that of unbounded water at ``p`` plus at each of ``p``'s reflections in
the six walls (a Neumann wall reflects the field point), the first
reflections only; in a round tank the floor's, the free surface's and the
curved wall's, taken as its tangent plane where ``p``'s radius meets it. What is neglected: the sensor's own reaction to the
object's field and to the walls' reflections (higher order in the object's
and the wall's distance), and degrees ``l >= 3`` of the sphere.

Example
-------
>>> import numpy as np
>>> from electrosense.meshes import preset
>>> from electrosense.meshes.objects import Sphere
>>> from electrosense.bem.free_field import meridian_field
>>> model = ObjectField(meridian_field(preset("angels-2"), edge_length_m=0.01, reach_m=0.1, spacing_m=0.004), 1.0)
>>> dK = model(np.zeros((1, 4)), None, (Sphere((0.0, 0.04, 0.0), float("inf"), 0.01),))
>>> dK.shape, bool(dK[0, 0, 0] > 0)      # a conductor beside the sensor: more conductance
((1, 2, 2), True)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from electrosense.bem.free_field import MeridianField, sphere_multipole_factors
from electrosense.meshes.pose import rotation_z
from electrosense.meshes.tank import Tank

__all__ = ["ObjectField", "wall_reflections", "sensor_object_field"]


def wall_reflections(tank, points_m: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """``[(reflected points (G, 3), reflection matrices (G, 3, 3)), ...]``: the points (G, 3) themselves (identity)
    and their first mirror images in the tank's boundaries: a box's six faces; a round tank's floor, free surface
    and curved wall, the wall as its vertical tangent plane where the point's radius meets it (radius at the
    point's height: a tapered wall's tilt is neglected).

    >>> from electrosense.meshes.cylinder_tank import CylinderTank
    >>> q, M = wall_reflections(CylinderTank(0.2, 0.3), np.array([[0.1, 0.1, 0.0]]))[1]
    >>> q.round(4).tolist(), (M[0, 0].round(4) + 0.0).tolist()
    ([[0.1828, 0.1828, 0.0]], [0.0, -1.0, 0.0])
    """
    p = np.asarray(points_m, float).reshape(-1, 3)
    eye = np.broadcast_to(np.eye(3), (len(p), 3, 3))
    out = [(p, eye)]
    if tank is None:
        return out
    lo, hi = tank.water_bounds_m
    if hasattr(tank, "radius_at"):      # a round tank: the curved wall, then the floor and the free surface
        rho = np.maximum(np.hypot(p[:, 0], p[:, 1]), 1e-12)
        n = np.column_stack([p[:, 0] / rho, p[:, 1] / rho, np.zeros(len(p))])       # the wall's normal there
        gap = np.asarray(tank.radius_at(p[:, 2]), float) - rho
        out.append((p + 2.0 * gap[:, None] * n, np.eye(3) - 2.0 * np.einsum("gi,gj->gij", n, n)))
        axes = (2,)
    else:
        axes = (0, 1, 2)
    for axis in axes:
        M = np.eye(3)
        M[axis, axis] = -1.0
        for plane in (lo[axis], hi[axis]):
            q = p.copy()
            q[:, axis] = 2 * plane - p[:, axis]
            out.append((q, np.broadcast_to(M, (len(p), 3, 3))))
    return out


@dataclass
class ObjectField:
    """dK of spheres in the water from the sensor's tabulated field (module doc)."""

    field: MeridianField
    sigma_S_per_m: float

    def field_at(self, poses: np.ndarray, tank: Tank | None, points_m: np.ndarray, hessian: bool = True):
        """Gradient (P, G, n, 3) and Hessian (P, G, n, 3, 3; None unless ``hessian``) of the sensor's unit
        solutions at tank-frame points (G, 3), the sensor at ``poses`` (P, 4), with the walls' reflections."""
        poses = np.asarray(poses, float).reshape(-1, 4)
        pts = np.asarray(points_m, float).reshape(-1, 3)
        P, G, n = len(poses), len(pts), self.field.n_electrodes
        R = rotation_z(poses[:, 3]).reshape(P, 3, 3)   # sensor -> tank
        t = poses[:, :3]
        g = np.zeros((P, G, n, 3))
        H = np.zeros((P, G, n, 3, 3)) if hessian else None
        for q, M in wall_reflections(tank, pts):
            local = np.einsum("pji,pgj->pgi", R, q[None, :, :] - t[:, None, :])   # R^T (q - t): the sensor's frame
            gl, Hl = self.field.derivatives(local.reshape(-1, 3))
            A = np.einsum("gab,pbc->pgac", M, R)   # d/dp of the reflected point, then to the tank frame
            g += np.einsum("pgac,pgnc->pgna", A, gl.reshape(P, G, n, 3))
            if hessian:
                H += np.einsum("pgac,pgncd,pgbd->pgnab", A, Hl.reshape(P, G, n, 3, 3), A)
        return g, H

    def __call__(self, poses: np.ndarray, tank: Tank | None, spheres) -> np.ndarray:
        """(P, n, n) the change of K that ``spheres`` (tank frame) make at the sensor's ``poses`` (P, 4)."""
        poses = np.asarray(poses, float).reshape(-1, 4)
        n = self.field.n_electrodes
        dK = np.zeros((len(poses), n, n))
        R = rotation_z(poses[:, 3]).reshape(len(poses), 3, 3)
        half = self.field.half_length_m - self.field.radius_m   # the axis segment of the sensor's capsule
        for s in spheres:
            local = np.einsum("pji,pj->pi", R, np.asarray(s.centre_m, float) - poses[:, :3])
            on_axis = np.column_stack([np.clip(local[:, 0], -half, half), np.zeros((len(local), 2))])
            if np.min(np.linalg.norm(local - on_axis, axis=1)) < self.field.radius_m + s.radius_m:
                raise ValueError("the sphere would touch the sensor at a logged pose")
            contrast = np.inf if np.isinf(s.conductivity_S_per_m) else s.conductivity_S_per_m / self.sigma_S_per_m
            d1, d2 = sphere_multipole_factors(s.radius_m, contrast)
            g, H = self.field_at(poses, tank, np.asarray(s.centre_m, float)[None])
            g, H = g[:, 0], H[:, 0]
            dK += self.sigma_S_per_m * (d1 * np.einsum("pia,pja->pij", g, g)
                                        + d2 * np.einsum("piab,pjab->pij", H, H))
        return dK

    def unit_dipoles(self, poses: np.ndarray, tank: Tank | None, points_m: np.ndarray) -> np.ndarray:
        """(P, G, n, n) the change of K per unit dipole strength (chi b^3 = 1 m^3) at each of ``points_m`` (G, 3):
        the dipole term alone, for scans over places."""
        g, _ = self.field_at(poses, tank, points_m, hessian=False)
        return self.sigma_S_per_m * 4 * np.pi * np.einsum("pgia,pgja->pgij", g, g)


def sensor_object_field(sensor, sigma_S_per_m: float, edge_length_m: float | None = None) -> ObjectField:
    """The :class:`ObjectField` of ``sensor``, its table kept on disk (``meridian-fields`` under the cache root,
    keyed by the sensor's geometry, the mesh edge and the model code's version)."""
    import hashlib
    import json
    import os

    from electrosense.bem.block_cache import cache_root
    from electrosense.bem.free_field import meridian_field
    from electrosense.validation.simulation.models import code_version

    geometry = {k: v for k, v in sensor.to_dict().items() if k not in ("name", "notes")}
    key = hashlib.sha256(json.dumps({"sensor": geometry, "edge": repr(edge_length_m), "code": code_version()},
                                    sort_keys=True).encode()).hexdigest()[:24]
    path = cache_root() / "meridian-fields" / f"{key}.npz"
    try:
        with np.load(path) as z:
            table = MeridianField(z["x_m"], z["r_m"], z["u"], float(z["radius_m"]), float(z["half_length_m"]))
    except (OSError, ValueError, KeyError, EOFError):
        table = meridian_field(sensor, edge_length_m=edge_length_m)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            partial = path.with_name(f"{key}.{os.getpid()}.partial.npz")
            np.savez(partial, x_m=table.x_m, r_m=table.r_m, u=table.u, radius_m=table.radius_m,
                     half_length_m=table.half_length_m)
            os.replace(partial, path)
        except OSError:
            pass   # a table not kept is computed again next time
    return ObjectField(table, sigma_S_per_m)
