"""Forward models for the diagnosis: nodal conductance K at many poses, for a modified scene.

The diagnosis asks one question of a simulator, again and again with other
inputs: *what is K (P, n, n) at these poses, in this tank, with these
objects?* (the water's conductivity is fixed at the nominal value; K is
proportional to it, so a conductivity change is a scale applied afterwards).
Two kinds answer it:

* :class:`ModelSimulator`: the project's models through
  :func:`electrosense.validation.simulation.models.simulate` (``"psm"``: the calibrated PSM,
  vectorised; ``"bem"``: the BEM pose sweep), with a memo of the answers so
  that a fit never asks twice for the same scene;
* :class:`PointElectrodeSimulator`: a small, self-contained point-electrode
  model (free-space potential coefficients, box images, dipole spheres). It
  is the stand-in used when the PSM cannot be imported, and in the unit tests
  of the diagnosis machinery; it is *not* a replacement for the PSM.

Both are callables ``sim(poses, tank, objects) -> K`` with ``.name``,
``.sensor`` and ``.sigma_S_per_m``.

Example
-------
>>> import numpy as np
>>> from electrosense.meshes.sensor import preset
>>> from electrosense.meshes.tank import Tank
>>> sim = PointElectrodeSimulator(preset("angels-4"), 0.0354)
>>> K = sim(np.array([[0.0, 0.0, 0.0, 0.0]]), Tank((1.0, 1.0, 1.0)), ())
>>> K.shape, bool(np.allclose(K.sum(axis=-1), 0.0, atol=1e-15))
((1, 4, 4), True)
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np

from electrosense.meshes.objects import Sphere
from electrosense.meshes.pose import sensor_to_tank
from electrosense.meshes.sensor import SensorDescription
from electrosense.meshes.tank import Tank
from electrosense.psm.contact import (
    electrode_areas_m2,  # wetted areas: a cap of height h has 2 pi r h
    series_contact,
)
from electrosense.psm.images import box_images
from electrosense.psm.objects import contrast

__all__ = ["ModelSimulator", "PSMEffectModel", "IMAGE_CHANGE_TOLERANCE", "IMAGE_PROBE_STEP_M", "CompositeEffectModel", "kelvin_sphere_term", "geometric_psm", "PointElectrodeSimulator", "electrode_areas_m2", "series_contact", "receiver_currents", "sphere_dipole_m3"]


# ----------------------------------------------------------------------------- helpers



def receiver_currents(K_S: np.ndarray, emitter: int) -> np.ndarray:
    """Bench currents (..., n-1) per volt: into each receiver, all receivers at one potential."""
    e = emitter - 1
    n = K_S.shape[-1]
    rec = [k for k in range(n) if k != e]
    return -K_S[..., rec, e]


def _key(*parts) -> str:
    h = hashlib.sha1()
    for p in parts:
        if isinstance(p, np.ndarray):
            h.update(np.ascontiguousarray(p, dtype=float).tobytes())
            h.update(str(p.shape).encode())
        else:
            h.update(repr(p).encode())
    return h.hexdigest()


# ------------------------------------------------------------------------ the models
@dataclass
class ModelSimulator:
    """K at poses through :func:`electrosense.validation.simulation.models.simulate` (``"psm"`` or ``"bem"``), memoised.

    Parameters
    ----------
    model : {"psm", "bem"}
    sensor : SensorDescription
    sigma_S_per_m : float
    options : dict
        Passed on to :func:`electrosense.validation.simulation.models.simulate` (``psm_model``,
        ``edge_length_m``, ``images``...).
    """

    model: str
    sensor: SensorDescription
    sigma_S_per_m: float
    options: dict = field(default_factory=dict)
    calls: int = 0
    _memo: dict = field(default_factory=dict, repr=False)

    @property
    def name(self) -> str:
        return self.model

    def __call__(self, poses, tank: Tank | None, objects=(), contact_impedance_ohm_m2=None) -> np.ndarray:
        from electrosense.validation.simulation.models import simulate

        poses = np.asarray(poses, dtype=float)
        key = _key(poses, tank, tuple(objects), contact_impedance_ohm_m2)
        if key not in self._memo:
            self.calls += 1
            C = simulate(
                self.model, self.sensor, poses, tank, self.sigma_S_per_m, objects=tuple(objects),
                contact_impedance_ohm_m2=contact_impedance_ohm_m2, **self.options,
            )
            K = C.K_S * (self.sigma_S_per_m / C.sigma_S_per_m)
            if len(self._memo) > 4096:
                self._memo.clear()
            self._memo[key] = K.reshape(len(poses), self.sensor.n_electrodes, self.sensor.n_electrodes)
        return self._memo[key]


def geometric_psm(sensor: SensorDescription, calibrated=None):
    """A PSM with its spheres at the electrodes' geometric centres and the calibrated radii.

    The calibrated PSM places its spheres where they best reproduce the
    free-space conductance, which for end caps is well beyond the real
    electrode (angels-4: 10.8 cm from the middle for a cap centred at
    9.5 cm). Far from the walls that does not matter; within a few
    centimetres of a wall, or of an object, the images see the sphere where
    it is, and the model's *sensitivity* to the wall or the object is off by
    a factor of two or more. With the spheres where the electrodes are, the
    changes of K caused by a moved wall, a shifted pose or another depth
    follow the BEM within about 10 % (see studies/diagnosis_blind.py); the
    absolute level is off by a few percent, which a relative change does not
    see.
    """
    from electrosense.psm import PolySphericalModel

    if calibrated is None:
        from electrosense.validation.simulation.models import calibrated_psm

        calibrated = calibrated_psm(sensor)
    if sensor.has_sectors:   # the sector model's currents already leave where the electrodes are
        return calibrated
    return PolySphericalModel(
        radii_m=np.asarray(calibrated.radii_m, float), centres_m=sensor.electrode_centres_m,
        emitter=sensor.emitter, electrode_areas_m2=electrode_areas_m2(sensor),
    )


#: truncation error of the PSM's image series allowed in a change of K, relative to that change
#: (:meth:`PSMEffectModel.choose_image_shells`). The diagnosis takes an effect model's change to first order
#: from the BEM wherever it has one (:mod:`.wall_gradient`, :mod:`.pose_gradient`): the series' error there
#: cancels to first order, and 1 % of a change of 4x the noise is 0.04 of the noise where it does not.
IMAGE_CHANGE_TOLERANCE = 1e-2
#: the probe changes of :meth:`PSMEffectModel.choose_image_shells`: walls, free surface and pose moved by this (m)
IMAGE_PROBE_STEP_M = 0.01


def effect_objects(objects) -> tuple:
    """The objects an effect model takes: the balls (the PSM's dipole term, Kelvin's spheres). A box or a pole is
    left out of the effect model, whose changes are then computed without it; the baseline (the BEM, a tank map)
    carries it. A baseline of the PSM itself refuses it.

    >>> from electrosense.meshes.objects import Cylinder
    >>> [type(o).__name__ for o in effect_objects((Sphere((0, 0, 0), radius_m=0.02), Cylinder((0.2, 0, 0))))]
    ['Sphere']
    """
    return tuple(o for o in objects if isinstance(o, Sphere))


@dataclass
class PSMEffectModel:
    """The PSM as effect model: :func:`electrosense.psm.conductance` with a fixed image series.

    An effect model is only ever asked for a *change*: the diagnosis applies
    ``K_eff(changed) / K_eff(nominal)`` to its baseline. The number of image
    shells is therefore chosen once, on the first tank it sees, by how well the
    series has converged in such changes (:meth:`choose_image_shells`), not in
    K itself, and then kept fixed so that K varies smoothly with the tank's
    size (finite-difference sensitivities would otherwise see the series'
    steps). The absolute K converges more slowly than its changes: the far
    images add to every entry a smooth part that mostly divides out of a
    change. Measured in a shallow 0.98 x 0.57 m tank (25.7 cm of water, 5
    electrodes, passes near the walls), against 32 shells: K needs 16 shells
    to settle to 1e-5 of its largest entry; with 12, the changes for a wall or
    the sensor moved by 1 cm are right to 1e-4 of themselves, for the free
    surface (the slab's far field, the slowest) to 7e-3; a call then costs
    0.05 s instead of 0.12 s at 75 poses.

    Parameters
    ----------
    sensor : SensorDescription
    sigma_S_per_m : float
    model : psm.PolySphericalModel, optional
        Default: :func:`geometric_psm` of ``sensor`` (the calibrated radii,
        the spheres at the electrodes' centres).
    image_shells : int, optional
        Fixed here; default: :meth:`choose_image_shells` on the first tank.
    """

    sensor: SensorDescription
    sigma_S_per_m: float
    model: object = None
    image_shells: int | None = None
    calls: int = 0

    def __post_init__(self):
        if self.model is None:
            self.model = geometric_psm(self.sensor)

    @property
    def name(self) -> str:
        return "psm"

    def _K(self, poses, tank, objects=(), contact_impedance_ohm_m2=None, image_shells=None) -> np.ndarray:
        from electrosense.psm.conductance import conductance_array

        return conductance_array(self.model, poses, self.sigma_S_per_m, tank=tank, objects=tuple(objects),
                                 contact_impedance_ohm_m2=contact_impedance_ohm_m2, sensor=self.sensor,
                                 image_shells=image_shells)[0]

    def choose_image_shells(self, poses, tank: Tank, tolerance: float = IMAGE_CHANGE_TOLERANCE,
                            step_m: float = IMAGE_PROBE_STEP_M) -> int:
        """The fewest shells N (4, 8, ...) whose changes of K agree with N + 4's to ``tolerance`` of the change.

        Three probe changes, each by ``step_m``: the walls (the tank wider and
        longer), the free surface (higher, or lower in a full tank) and the
        sensor (moved towards the middle), at the poses nearest each boundary
        and a spread of the others. A change is that of every mutual
        conductance, ``delta = K_ij(changed) / K_ij(nominal) - 1``; the series
        with N shells is accepted when ``max |delta_N - delta_{N+4}|`` is
        below ``tolerance * max |delta_{N+4}|`` for every probe (the next N is
        much more accurate, so the difference estimates delta_N's error).

        Examples
        --------
        >>> import numpy as np
        >>> from electrosense.meshes.sensor import preset
        >>> m = PSMEffectModel(preset("angels-4"), 0.0354)
        >>> m.choose_image_shells(np.array([[0.3, 0.0, -0.25, 0.0]]), Tank((1.0, 1.0, 1.0), 0.5)) in (4, 8, 12, 16)
        True
        """
        from electrosense.psm.conductance import MAX_IMAGE_SHELLS, boundary_probe_indices, sphere_centres_m

        poses = np.asarray(poses, dtype=float).reshape(-1, 4)
        poses = poses[boundary_probe_indices(sphere_centres_m(self.model, poses), tank)]
        lx, ly, lz = tank.size_m
        full = tank.water_depth_m + step_m > lz
        moved = poses.copy()
        moved[:, :2] -= step_m * np.sign(moved[:, :2])
        probes = [(poses, Tank((lx + 2 * step_m, ly + 2 * step_m, lz), tank.water_depth_m)),
                  (poses, Tank((lx, ly, lz), tank.water_depth_m + (-step_m if full else step_m))),
                  (moved, tank)]
        off = ~np.eye(self.model.n, dtype=bool)

        def changes(shells):
            K0 = self._K(poses, tank, image_shells=shells)[:, off]
            return [self._K(p, t, image_shells=shells)[:, off] / K0 - 1.0 for p, t in probes]

        previous = changes(4)
        for shells in range(4, MAX_IMAGE_SHELLS + 1, 4):
            following = changes(shells + 4)
            if all(np.max(np.abs(a - b)) <= tolerance * np.max(np.abs(b)) for a, b in zip(previous, following)):
                return shells
            previous = following
        return MAX_IMAGE_SHELLS

    def __call__(self, poses, tank: Tank | None, objects=(), contact_impedance_ohm_m2=None) -> np.ndarray:
        self.calls += 1
        poses = np.asarray(poses, dtype=float).reshape(-1, 4)
        objects = effect_objects(objects)
        if self.sensor.has_sectors:   # the sector PSM (psm.sectors): a fixed image series already
            from electrosense.psm.sectors import sector_conductance

            return sector_conductance(self.model, poses, self.sigma_S_per_m, tank=tank, objects=tuple(objects),
                                      contact_impedance_ohm_m2=contact_impedance_ohm_m2).K_S
        if tank is not None and self.image_shells is None:
            self.image_shells = self.choose_image_shells(poses, tank)
        return self._K(poses, tank, objects, contact_impedance_ohm_m2,
                       self.image_shells if tank is not None else None)


@dataclass
class PointElectrodeSimulator:
    """A stand-in forward model: point electrodes with box images and dipole spheres.

    Electrode p is a sphere of radius ``radius_factor * sensor.radius_m`` at its
    axial centre. The potential coefficients are free-space ``1/(4 pi sigma r)``
    plus the images of an insulating box summed over ``shells`` cubic shells,
    plus the dipole of each spherical object (``chi b^3``, the PSM's small-object
    term). Receiver currents follow from the isolated-sensor conductance
    ``K = P (P^T M P)^-1 P^T``.

    Only meant for testing the diagnosis machinery and as a fallback; the PSM
    is the model of record.
    """

    sensor: SensorDescription
    sigma_S_per_m: float
    radius_factor: float = 0.72
    shells: int = 2
    calls: int = 0
    radii_m: np.ndarray | None = None
    kelvin: bool = False

    @property
    def name(self) -> str:
        return "point-electrodes"

    def __call__(self, poses, tank: Tank | None, objects=(), contact_impedance_ohm_m2=None) -> np.ndarray:
        self.calls += 1
        poses = np.asarray(poses, dtype=float).reshape(-1, 4)
        objects = effect_objects(objects)
        n = self.sensor.n_electrodes
        c = sensor_to_tank(self.sensor.electrode_centres_m, poses)  # (P, n, 3)
        d = c[:, :, None, :] - c[:, None, :, :]
        r = np.linalg.norm(d, axis=-1)
        a = self.radius_factor * self.sensor.radius_m if self.radii_m is None else np.asarray(self.radii_m, float)
        a = np.broadcast_to(a, (n,))
        M = np.where(np.eye(n, dtype=bool), 1.0 / a[None, :, None], 1.0 / np.where(r > 0, r, 1.0))
        if tank is not None:
            M = M + self._images(c, tank)
        for obj in objects:
            M = M + self._dipole(c, obj)
        M = M / (4 * np.pi * self.sigma_S_per_m)
        Pm = np.vstack([np.eye(n - 1), -np.ones((1, n - 1))])
        G = np.linalg.inv(np.einsum("ip,Pij,jq->Ppq", Pm, M, Pm))
        K = np.einsum("ip,Ppq,jq->Pij", Pm, G, Pm)
        if contact_impedance_ohm_m2 is not None:
            z = np.broadcast_to(np.asarray(contact_impedance_ohm_m2, dtype=float), (n,))
            K = series_contact(K, z / electrode_areas_m2(self.sensor))
        return 0.5 * (K + np.swapaxes(K, -1, -2))

    def _images(self, c: np.ndarray, tank: Tank) -> np.ndarray:
        """Sum over the insulating box's images (the PSM's, ``shells`` cubic shells) of 1 / |c_p - image(c_q)|."""
        images = box_images(tank, self.shells, trapezoid=False).apply(c)  # (Q, P, n, 3)
        d = c[None, :, :, None, :] - images[:, :, None, :, :]  # (Q, P, p, q, 3)
        return np.sum(1.0 / np.linalg.norm(d, axis=-1), axis=0)

    def _dipole(self, c: np.ndarray, obj) -> np.ndarray:
        if not isinstance(obj, Sphere):
            raise ValueError(f"the point-electrode model handles spheres only, got {type(obj).__name__}")
        xo = np.asarray(obj.centre_m)
        u = c - xo  # (P, n, 3): c_p - x_o
        dist = np.linalg.norm(u, axis=-1)
        if np.any(dist <= obj.radius_m + self.sensor.radius_m):
            raise ValueError("a sphere overlaps an electrode")
        if self.kelvin and np.isinf(obj.conductivity_S_per_m):
            return kelvin_sphere_term(c, xo, obj.radius_m)
        ru3 = dist**3
        dot = -np.einsum("Ppk,Pqk->Ppq", u, u)  # (c_p - x_o) . (x_o - c_q)
        return sphere_dipole_m3(obj, self.sigma_S_per_m) * dot / (ru3[:, :, None] * ru3[:, None, :])


def kelvin_sphere_term(c: np.ndarray, centre_m, radius_m: float) -> np.ndarray:
    """Potential coefficients (P, n, n), in units of 1/(4 pi sigma), added by a floating perfectly conducting sphere.

    Kelvin's image of a point source q at distance d from the centre: -q b/d at
    b^2/d from the centre, and +q b/d at the centre (the sphere floats: no net
    current). Exact for point sources (all multipoles, not the dipole alone),
    which matters when the sphere is within a few radii of the sensor.
    """
    xo = np.asarray(centre_m, float)
    u = c - xo
    d = np.linalg.norm(u, axis=-1)  # (P, n)
    image = xo + (radius_m**2 / d**2)[..., None] * u
    w = radius_m / d
    d_image = np.linalg.norm(c[:, :, None, :] - image[:, None, :, :], axis=-1)  # (P, p, q)
    term = -w[:, None, :] / d_image + w[:, None, :] / d[:, :, None]
    return 0.5 * (term + np.swapaxes(term, 1, 2))


@dataclass
class CompositeEffectModel:
    """The geometric PSM for the scene, with spheres put in by the point-electrode model (Kelvin images).

    ``K = K_psm(poses, tank) * K_pt(poses, tank, spheres) / K_pt(poses, tank)`` entry by entry (zero row
    sums restored): the tank, depth and pose come from the PSM; what a conducting sphere near the sensor
    does comes from Kelvin's exact image of each electrode (the dipole term alone underestimates a sphere
    within a few radii of the sensor by 30-80 %, see studies/diagnosis_blind.py).
    """

    psm: PSMEffectModel
    points: PointElectrodeSimulator
    calls: int = 0
    scenes: dict = field(default_factory=dict, repr=False, compare=False)  # see _memo

    @property
    def name(self) -> str:
        return "psm+kelvin"

    def _memo(self, model, poses, tank, contact_impedance_ohm_m2) -> np.ndarray:
        """``model(poses, tank, ())``, remembered for the last few scenes: a sphere moved by a fit leaves the
        scene without it unchanged."""
        import hashlib

        poses = np.ascontiguousarray(poses, float)
        key = (id(model), hashlib.sha1(poses.tobytes()).hexdigest(), tank,
               None if contact_impedance_ohm_m2 is None else np.asarray(contact_impedance_ohm_m2, float).tobytes())
        memo = self.scenes
        if key not in memo:
            if len(memo) >= 16:
                memo.pop(next(iter(memo)))
            memo[key] = model(poses, tank, (), contact_impedance_ohm_m2)
        return memo[key]

    @property
    def sensor(self):
        return self.psm.sensor

    def __call__(self, poses, tank: Tank | None, objects=(), contact_impedance_ohm_m2=None) -> np.ndarray:
        self.calls += 1
        K = self._memo(self.psm, poses, tank, contact_impedance_ohm_m2)
        objects = effect_objects(objects)
        if not objects:
            return K
        ratio = self.points(poses, tank, tuple(objects)) / self._memo(self.points, poses, tank, None)
        K = K * ratio
        n = K.shape[-1]
        off = K * (1 - np.eye(n))
        return off - np.eye(n) * off.sum(axis=-1, keepdims=True)


def sphere_dipole_m3(obj, sigma_water_S_per_m: float) -> float:
    """Dipole strength chi b^3 (m^3) of a sphere (the PSM's contrast chi, 1 for a conductor)."""
    return contrast(obj.conductivity_S_per_m, sigma_water_S_per_m) * obj.radius_m**3
